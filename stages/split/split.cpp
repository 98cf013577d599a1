// Isoparametric boundary-layer splitting; see split.hpp for the method and the node keys.
#include "stages/split/split.hpp"

#include "engine/stage.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/topology.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <memory>
#include <sstream>
#include <unordered_map>
#include <unordered_set>

namespace meshflow::split {

namespace {

using model::ElementBlock;
using model::ElementRef;
using model::Lattice;
using model::Mesh;
using model::Shape;
using model::Vec3;

constexpr std::uint32_t kNone = UINT32_MAX;

// ---------------------------------------------------------------------------------------
// Fine-lattice points of a split pattern and where they lie in the macro element.

enum class Loc : std::uint8_t { Reuse, Interior, Edge, Face };

// A macro edge direction: local end vertices a, b, wall flag (0 none, 1 wall at a, 2 at b),
// number of fine intervals N, offset of the point from a.
struct EdgeDesc {
  std::uint8_t a = 0, b = 0, flag = 0;
  std::uint32_t N = 0, off = 0;
};

struct FinePoint {
  Loc loc = Loc::Interior;
  std::int8_t mface = -1, medge = -1;
  int reuse = -1;                 // Loc::Reuse: local node of the macro element
  std::uint8_t fv[4] = {};        // Loc::Face: local vertices of the face
  EdgeDesc e;                     // Loc::Edge
  EdgeDesc d1[2], d2[2];          // Loc::Face: the two parallel edges of each face direction
};

struct Pattern {
  Shape shape = Shape::Prism;
  int P = 1, L = 1;
  int dirsplit[3] = {0, 0, 0};  // 0 none, -1 wall at parameter -1, +1 wall at +1
  int N[3] = {0, 0, 0};         // fine intervals per direction
  int T = 0;                    // prism: nodes of the triangle
  std::vector<int> tri_index;   // prism: (i*(P+1)+j) -> triangle index
  std::vector<std::array<int, 3>> fc;  // fine coordinates of each fine point
  std::vector<FinePoint> pts;
  std::vector<double> tab[3];     // 1D Lagrange values, (N_d+1) x (P+1)
  std::vector<int> lat_index;     // (i + (P+1)(j + (P+1)k)) -> local node of the macro element
  int nsub = 0, nps = 0;
  std::vector<std::uint32_t> sub_nodes;     // nsub x nps fine indices
  std::vector<std::uint8_t> face_split;     // per macro face
  std::vector<std::vector<int>> face_subs;  // per macro face: subs whose face f lies on it
  std::vector<std::vector<std::uint32_t>> face_pts;  // per macro face: keyed fine points on it
  std::vector<EdgeDesc> split_edges;        // macro edges that are subdivided

  std::size_t index(int I, int J, int K) const {
    if (shape == Shape::Prism) return tri_index[I * (P + 1) + J] + std::size_t(T) * K;
    return I + std::size_t(N[0] + 1) * (J + std::size_t(N[1] + 1) * K);
  }
};

double lagrange1d(int P, int l, double x) {
  double xl = -1 + 2.0 * l / P, v = 1;
  for (int m = 0; m <= P; ++m)
    if (m != l) v *= (x - (-1 + 2.0 * m / P)) / (xl - (-1 + 2.0 * m / P));
  return v;
}

// Parameter in [-1,1] of fine coordinate F along a direction of a hex or the prism axis.
double fine_param(const Pattern& pt, const std::vector<double>& cuts, int d, int F) {
  int P = pt.P;
  if (!pt.dirsplit[d]) return -1 + 2.0 * F / P;
  int Fw = pt.dirsplit[d] < 0 ? F : pt.N[d] - F;  // distance from the wall, fine units
  int m = std::min(Fw / P, pt.L - 1), l = Fw - m * P;
  double t = l == 0 ? cuts[m] : l == P ? cuts[m + 1] : cuts[m] + (cuts[m + 1] - cuts[m]) * l / P;
  return pt.dirsplit[d] < 0 ? -1 + 2 * t : 1 - 2 * t;
}

int hexv(int s0, int s1, int s2) {
  static const int v[2][2][2] = {{{0, 4}, {3, 7}}, {{1, 5}, {2, 6}}};  // [s0][s1][s2]
  return v[s0][s1][s2];
}

int local_edge(Shape s, int a, int b) {
  const auto& ev = model::edge_vertices(s);
  for (std::size_t e = 0; e < ev.size(); ++e)
    if ((ev[e][0] == a && ev[e][1] == b) || (ev[e][0] == b && ev[e][1] == a)) return int(e);
  return -1;
}

// Hex face f -> (direction, side).
std::pair<int, int> hex_face_dir(int f) {
  const auto& fv = model::face_vertices(Shape::Hex)[f];
  const auto& ref = model::reference_nodes(Shape::Hex, 1);
  for (int d = 0; d < 3; ++d) {
    bool same = true;
    for (int v : fv) same = same && ref[v][d] == ref[fv[0]][d];
    if (same) return {d, ref[fv[0]][d] > 0 ? 1 : 0};
  }
  return {-1, -1};
}

bool on_face(const Pattern& pt, int f, const std::array<int, 3>& c) {
  if (pt.shape == Shape::Prism) {
    switch (f) {
      case 0: return c[2] == 0;
      case 1: return c[2] == pt.N[2];
      case 2: return c[1] == 0;
      case 3: return c[0] == 0;
      default: return c[0] + c[1] == pt.P;
    }
  }
  auto [d, s] = hex_face_dir(f);
  return c[d] == (s ? pt.N[d] : 0);
}

std::uint8_t wall_flag(int dirsplit) { return dirsplit < 0 ? 1 : dirsplit > 0 ? 2 : 0; }

Pattern make_pattern(Shape shape, int P, int L, const int dirsplit[3], const std::vector<double>& cuts) {
  Pattern pt;
  pt.shape = shape;
  pt.P = P;
  pt.L = L;
  for (int d = 0; d < 3; ++d) {
    pt.dirsplit[d] = L > 1 ? dirsplit[d] : 0;
    pt.N[d] = pt.dirsplit[d] ? L * P : P;
  }
  const auto& lat = model::lattice(shape, P);
  pt.lat_index.assign(std::size_t(P + 1) * (P + 1) * (P + 1), -1);
  for (std::size_t i = 0; i < lat.size(); ++i)
    pt.lat_index[lat[i][0] + (P + 1) * (lat[i][1] + (P + 1) * lat[i][2])] = int(i);
  auto latnode = [&](int i, int j, int k) { return pt.lat_index[i + (P + 1) * (j + (P + 1) * k)]; };

  // fine points
  if (shape == Shape::Prism) {
    pt.tri_index.assign(std::size_t(P + 1) * (P + 1), -1);
    for (int j = 0; j <= P; ++j)
      for (int i = 0; i + j <= P; ++i) pt.tri_index[i * (P + 1) + j] = pt.T++;
    pt.fc.resize(std::size_t(pt.T) * (pt.N[2] + 1));
    for (int K = 0; K <= pt.N[2]; ++K)
      for (int j = 0; j <= P; ++j)
        for (int i = 0; i + j <= P; ++i) pt.fc[pt.index(i, j, K)] = {i, j, K};
  } else {
    pt.fc.resize(std::size_t(pt.N[0] + 1) * (pt.N[1] + 1) * (pt.N[2] + 1));
    for (int K = 0; K <= pt.N[2]; ++K)
      for (int J = 0; J <= pt.N[1]; ++J)
        for (int I = 0; I <= pt.N[0]; ++I) pt.fc[pt.index(I, J, K)] = {I, J, K};
  }
  pt.pts.resize(pt.fc.size());
  for (std::size_t q = 0; q < pt.fc.size(); ++q) {
    auto F = pt.fc[q];
    FinePoint& fp = pt.pts[q];
    int ext[3];
    for (int d = 0; d < 3; ++d) ext[d] = F[d] == 0 ? 0 : F[d] == pt.N[d] ? 1 : -1;
    bool reuse = true;
    for (int d = 0; d < 3; ++d)
      if (pt.dirsplit[d] && ext[d] < 0) reuse = false;
    if (reuse) {
      int l[3];
      for (int d = 0; d < 3; ++d) l[d] = pt.dirsplit[d] ? (ext[d] ? P : 0) : F[d];
      fp.loc = Loc::Reuse;
      fp.reuse = latnode(l[0], l[1], l[2]);
      continue;
    }
    if (shape == Shape::Prism) {
      int i = F[0], j = F[1];
      std::uint8_t fl = wall_flag(pt.dirsplit[2]);
      int corner = (i == 0 && j == 0) ? 0 : (i == P && j == 0) ? 1 : (i == 0 && j == P) ? 2 : -1;
      if (corner >= 0) {
        fp.loc = Loc::Edge;
        fp.e = {std::uint8_t(corner), std::uint8_t(corner + 3), fl, std::uint32_t(pt.N[2]), std::uint32_t(F[2])};
        fp.medge = std::int8_t(local_edge(shape, corner, corner + 3));
        continue;
      }
      int ca, cb, pos, face;
      if (j == 0) ca = 0, cb = 1, pos = i, face = 2;
      else if (i == 0) ca = 0, cb = 2, pos = j, face = 3;
      else if (i + j == P) ca = 1, cb = 2, pos = j, face = 4;
      else {
        fp.loc = Loc::Interior;
        continue;
      }
      fp.loc = Loc::Face;
      fp.mface = std::int8_t(face);
      std::uint8_t a = std::uint8_t(ca), b = std::uint8_t(cb);
      fp.fv[0] = a, fp.fv[1] = b, fp.fv[2] = std::uint8_t(b + 3), fp.fv[3] = std::uint8_t(a + 3);
      fp.d1[0] = {a, b, 0, std::uint32_t(P), std::uint32_t(pos)};
      fp.d1[1] = {std::uint8_t(a + 3), std::uint8_t(b + 3), 0, std::uint32_t(P), std::uint32_t(pos)};
      fp.d2[0] = {a, std::uint8_t(a + 3), fl, std::uint32_t(pt.N[2]), std::uint32_t(F[2])};
      fp.d2[1] = {b, std::uint8_t(b + 3), fl, std::uint32_t(pt.N[2]), std::uint32_t(F[2])};
      continue;
    }
    int nfree = 0, fr[3], fixed = -1;
    for (int d = 0; d < 3; ++d) {
      if (ext[d] < 0) fr[nfree++] = d;
      else fixed = d;
    }
    if (nfree == 3) {
      fp.loc = Loc::Interior;
    } else if (nfree == 1) {
      int d = fr[0];
      int s0[3] = {ext[0], ext[1], ext[2]}, s1[3] = {ext[0], ext[1], ext[2]};
      s0[d] = 0, s1[d] = 1;
      fp.loc = Loc::Edge;
      fp.e = {std::uint8_t(hexv(s0[0], s0[1], s0[2])), std::uint8_t(hexv(s1[0], s1[1], s1[2])), wall_flag(pt.dirsplit[d]),
              std::uint32_t(pt.N[d]), std::uint32_t(F[d])};
      fp.medge = std::int8_t(local_edge(shape, fp.e.a, fp.e.b));
    } else {  // a face: one fixed direction
      int d1 = fr[0], d2 = fr[1];
      fp.loc = Loc::Face;
      auto vert = [&](int a1, int a2) {
        int s[3];
        s[fixed] = ext[fixed], s[d1] = a1, s[d2] = a2;
        return std::uint8_t(hexv(s[0], s[1], s[2]));
      };
      fp.fv[0] = vert(0, 0), fp.fv[1] = vert(1, 0), fp.fv[2] = vert(1, 1), fp.fv[3] = vert(0, 1);
      for (int s = 0; s < 2; ++s) {
        fp.d1[s] = {vert(0, s), vert(1, s), wall_flag(pt.dirsplit[d1]), std::uint32_t(pt.N[d1]), std::uint32_t(F[d1])};
        fp.d2[s] = {vert(s, 0), vert(s, 1), wall_flag(pt.dirsplit[d2]), std::uint32_t(pt.N[d2]), std::uint32_t(F[d2])};
      }
      for (int f = 0; f < 6; ++f)
        if (hex_face_dir(f) == std::pair<int, int>{fixed, ext[fixed]}) fp.mface = std::int8_t(f);
    }
  }

  // 1D tables (hex: every direction; prism: the axis)
  for (int d = (shape == Shape::Prism ? 2 : 0); d < 3; ++d) {
    pt.tab[d].resize(std::size_t(pt.N[d] + 1) * (P + 1));
    for (int F = 0; F <= pt.N[d]; ++F) {
      double x = fine_param(pt, cuts, d, F);
      for (int l = 0; l <= P; ++l) pt.tab[d][F * (P + 1) + l] = lagrange1d(P, l, x);
    }
  }

  // sub-elements, first layer at the wall
  int n[3];
  for (int d = 0; d < 3; ++d) n[d] = pt.dirsplit[d] ? L : 1;
  pt.nps = model::num_nodes(shape, P);
  pt.nsub = n[0] * n[1] * n[2];
  pt.sub_nodes.reserve(std::size_t(pt.nsub) * pt.nps);
  std::vector<std::array<int, 3>> subm;
  for (int w2 = 0; w2 < n[2]; ++w2)
    for (int w1 = 0; w1 < n[1]; ++w1)
      for (int w0 = 0; w0 < n[0]; ++w0) {
        int w[3] = {w0, w1, w2}, m[3];
        for (int d = 0; d < 3; ++d) m[d] = pt.dirsplit[d] > 0 ? n[d] - 1 - w[d] : w[d];
        subm.push_back({m[0], m[1], m[2]});
        for (const Lattice& l : lat) {
          int F[3];
          for (int d = 0; d < 3; ++d) F[d] = m[d] * P + l[d];
          pt.sub_nodes.push_back(std::uint32_t(pt.index(F[0], F[1], F[2])));
        }
      }
  // faces: which are subdivided, the sub-elements on them, their keyed points
  const auto& faces = model::face_vertices(shape);
  int nf = int(faces.size()), nv = model::num_vertices(shape);
  pt.face_split.assign(nf, 0);
  pt.face_subs.assign(nf, {});
  pt.face_pts.assign(nf, {});
  for (int f = 0; f < nf; ++f) {
    for (std::size_t q = 0; q < pt.pts.size(); ++q)
      if (on_face(pt, f, pt.fc[q]) && (pt.pts[q].loc == Loc::Edge || pt.pts[q].loc == Loc::Face)) {
        pt.face_split[f] = 1;
        pt.face_pts[f].push_back(std::uint32_t(q));
      }
    if (!pt.face_split[f]) continue;
    for (int s = 0; s < pt.nsub; ++s) {
      bool all = true;
      for (int v : faces[f]) all = all && on_face(pt, f, pt.fc[pt.sub_nodes[std::size_t(s) * pt.nps + v]]);
      if (all) pt.face_subs[f].push_back(s);
    }
  }
  (void)nv;
  // subdivided edges
  std::vector<std::uint8_t> seen(model::edge_vertices(shape).size(), 0);
  for (auto& fp : pt.pts)
    if (fp.loc == Loc::Edge && !seen[fp.medge]) {
      seen[fp.medge] = 1;
      pt.split_edges.push_back(fp.e);
    }
  return pt;
}

// ---------------------------------------------------------------------------------------
// Keys of shared points (integers and global node indices only).

using Key = std::array<std::uint32_t, 15>;

void edge_key(const EdgeDesc& d, const std::uint32_t* gv, std::uint32_t* out) {
  std::uint32_t ga = gv[d.a], gb = gv[d.b], flag = d.flag, off = d.off;
  if (ga > gb) {
    std::swap(ga, gb);
    flag = flag == 1 ? 2 : flag == 2 ? 1 : 0;
    off = d.N - off;
  }
  out[0] = ga, out[1] = gb, out[2] = flag, out[3] = d.N, out[4] = off;
}

Key make_key(const FinePoint& p, const std::uint32_t* gv) {
  Key k;
  k.fill(kNone);
  if (p.loc == Loc::Edge) {
    k[0] = 1;
    edge_key(p.e, gv, &k[1]);
    return k;
  }
  k[0] = 2;
  std::uint32_t f[4];
  for (int i = 0; i < 4; ++i) f[i] = gv[p.fv[i]];
  std::sort(f, f + 4);
  for (int i = 0; i < 4; ++i) k[1 + i] = f[i];
  std::uint32_t mn = f[0];
  auto pick = [&](const EdgeDesc* d) { return (gv[d[0].a] == mn || gv[d[0].b] == mn) ? d[0] : d[1]; };
  std::array<std::uint32_t, 5> e1, e2;
  edge_key(pick(p.d1), gv, e1.data());
  edge_key(pick(p.d2), gv, e2.data());
  if (e2 < e1) std::swap(e1, e2);
  std::copy(e1.begin(), e1.end(), k.begin() + 5);
  std::copy(e2.begin(), e2.end(), k.begin() + 10);
  return k;
}

// The shared points by their keys, grouped by what they lie on: a key is a group (a macro edge:
// its sorted end nodes, wall flag and fine intervals; a macro face: its sorted vertex nodes and
// the two edge groups through its lowest vertex) and the point's offsets in it, so a group's
// points are one array of ids (kNone: not created yet), found by one lookup of the group. One
// entry per shared point in a hash map cost ~100 bytes and an allocation each (Rotor 67:
// 11.7 s and 1.2 GB for its ~15 M shared points, 2.6 s more to free them); a group's array is
// 4 bytes a point and there are a few hundred thousand groups. The same keys, the same ids in
// the same order (the first macro element in mesh order to reach a point creates it).
class SharedPoints {
 public:
  // The id slot of the point with key k, its group created (all points kNone) when new.
  std::uint32_t& slot(const Key& k) {
    Group g;
    std::uint32_t o1, o2, n1, n2;
    split(k, g, o1, o2, n1, n2);
    const std::size_t* base = recent(g);
    if (!base) {
      auto [at, fresh] = groups_.try_emplace(g, ids_.size());
      if (fresh) ids_.resize(ids_.size() + (std::size_t(n1) + 1) * (std::size_t(n2) + 1), kNone);
      base = remember(g, at->second);
    }
    return ids_[*base + std::size_t(o1) * (n2 + 1) + o2];
  }
  // The id of the point with key k; kNone when it was never created.
  std::uint32_t find(const Key& k) const {
    Group g;
    std::uint32_t o1, o2, n1, n2;
    split(k, g, o1, o2, n1, n2);
    auto it = groups_.find(g);
    if (it == groups_.end()) return kNone;
    return ids_[it->second + std::size_t(o1) * (n2 + 1) + o2];
  }

 private:
  using Group = std::array<std::uint32_t, 13>;
  struct GroupHash {
    std::size_t operator()(const Group& k) const {
      std::uint64_t h = 0x9E3779B97F4A7C15ull;
      for (auto w : k) {
        h ^= w + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
        h *= 0xBF58476D1CE4E5B9ull;
      }
      return std::size_t(h ^ (h >> 31));
    }
  };
  // An edge key (1, a, b, flag, N, off): group (1, a, b, flag, N), offset off in 0..N. A face
  // key (2, f0..f3, edge1 (a, b, flag, N1, off1), edge2 (.., N2, off2)): group (2, f0..f3, the
  // edges without their offsets), offsets (off1, off2) in (0..N1, 0..N2).
  static void split(const Key& k, Group& g, std::uint32_t& o1, std::uint32_t& o2, std::uint32_t& n1, std::uint32_t& n2) {
    g.fill(kNone);
    if (k[0] == 1) {
      std::copy(k.begin(), k.begin() + 5, g.begin());
      o1 = k[5], o2 = 0, n1 = k[4], n2 = 0;
    } else {
      std::copy(k.begin(), k.begin() + 9, g.begin());
      std::copy(k.begin() + 10, k.begin() + 14, g.begin() + 9);
      o1 = k[9], o2 = k[14], n1 = k[8], n2 = k[13];
    }
    if (o1 > n1 || o2 > n2) throw StageError("split: internal error: a shared point's offset is outside its edge or face");
  }
  // The groups of the last few lookups (a macro element's points lie on its few edges and faces).
  const std::size_t* recent(const Group& g) const {
    for (int i = 0; i < nrecent_; ++i)
      if (recent_[i].first == g) return &recent_[i].second;
    return nullptr;
  }
  const std::size_t* remember(const Group& g, std::size_t base) {
    auto& r = recent_[nrecent_ < kRecent ? nrecent_++ : (next_ = (next_ + 1) % kRecent)];
    r = {g, base};
    return &r.second;
  }
  static constexpr int kRecent = 16;
  std::array<std::pair<Group, std::size_t>, kRecent> recent_;
  int nrecent_ = 0, next_ = 0;
  std::unordered_map<Group, std::size_t, GroupHash> groups_;
  std::vector<std::uint32_t> ids_;
};

using FaceKey = std::array<std::uint32_t, 4>;
FaceKey face_key(const std::uint32_t* v, int n) {
  FaceKey k{kNone, kNone, kNone, kNone};
  n = std::clamp(n, 0, 4);
  for (int i = 0; i < n; ++i) k[i] = v[i];
  std::sort(k.begin(), k.begin() + n);
  return k;
}
struct FaceKeyHash {
  std::size_t operator()(const FaceKey& k) const {
    std::uint64_t h = 0;
    for (auto w : k) h = (h ^ w) * 0x100000001B3ull + 0x9E3779B97F4A7C15ull;
    return std::size_t(h ^ (h >> 29));
  }
};

// Reversal permutation of a face element (tri/quad) of order P: out[k] = in[rev[k]].
std::vector<int> reversal(Shape s, int P) {
  const auto& lat = model::lattice(s, P);
  std::map<Lattice, int> at;
  for (std::size_t i = 0; i < lat.size(); ++i) at[lat[i]] = int(i);
  std::vector<int> rev(lat.size());
  for (std::size_t k = 0; k < lat.size(); ++k) rev[k] = at.at({lat[k][1], lat[k][0], lat[k][2]});
  return rev;
}

std::string where(const Mesh& m, std::uint32_t node) {
  std::ostringstream s;
  s << "(" << m.x[node] << ", " << m.y[node] << ", " << m.z[node] << ")";
  return s.str();
}

struct Macro {
  std::uint32_t block = 0, elem = 0;
  int pattern = 0;
  int walls = 0;
};

const double kGaussX[8] = {-0.9602898564975363, -0.7966664774136267, -0.5255324099163290, -0.1834346424956498,
                           0.1834346424956498,  0.5255324099163290,  0.7966664774136267,  0.9602898564975363};
const double kGaussW[8] = {0.1012285362903763, 0.2223810344533745, 0.3137066458778873, 0.3626837833783620,
                           0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763};

// The wall-normal line of direction d through the wall face's centroid, from the wall (t = 0)
// to t = t1: its 8 Gauss points' basis gradients, the same for every macro element of a
// pattern (computed once per pattern and direction: per element they were 2 s of Rotor 67's
// split), and its mapped length.
struct NormalLine {
  double t1 = 1;
  int d = 0, n = 0;
  std::vector<double> dN;  // 8 x 3n
  NormalLine(Shape shape, int P, int d_, int dirsplit, double t1_) : t1(t1_), d(d_) {
    const auto& b = model::LagrangeBasis::get(shape, P);
    n = b.size();
    dN.resize(8 * 3 * std::size_t(n));
    for (int g = 0; g < 8; ++g) {
      const double t = 0.5 * t1 * (kGaussX[g] + 1);
      Vec3 xi = shape == Shape::Prism ? Vec3{1.0 / 3, 1.0 / 3, 0} : Vec3{0, 0, 0};
      xi[d] = dirsplit < 0 ? -1 + 2 * t : 1 - 2 * t;
      b.grad(xi, &dN[std::size_t(g) * 3 * n]);
    }
  }
  // the length for node coordinates X (3n)
  double length(const double* X) const {
    double len = 0;
    for (int g = 0; g < 8; ++g) {
      double J[9];
      model::jacobian(X, &dN[std::size_t(g) * 3 * n], n, J);
      const double s = 2 * std::sqrt(J[d] * J[d] + J[3 + d] * J[3 + d] + J[6 + d] * J[6 + d]);
      len += 0.5 * t1 * kGaussW[g] * s;
    }
    return len;
  }
};

}  // namespace

std::vector<double> layer_cuts(int layers, double ratio) {
  if (layers < 1) throw StageError("split: layers must be at least 1");
  if (!(ratio >= 1)) throw StageError("split: ratio must be at least 1");
  std::vector<double> h(layers), t(layers + 1, 0.0);
  double sum = 0, p = 1;
  for (int k = 0; k < layers; ++k) h[k] = p, sum += p, p *= ratio;
  double acc = 0;
  for (int k = 0; k < layers; ++k) acc += h[k], t[k + 1] = acc / sum;
  t[layers] = 1;
  return t;
}

double ratio_for_first_fraction(int layers, double fraction) {
  auto first = [&](double r) { return layer_cuts(layers, r)[1]; };
  if (fraction > first(1.0) * (1 + 1e-12))
    throw StageError("split: first_height is too large: even uniform layers (ratio 1) give a thinner first layer; "
                     "lower first_height or the number of layers");
  if (fraction >= first(1.0)) return 1.0;
  if (fraction < first(10.0))
    throw StageError("split: first_height is too small: it needs a growth ratio above 10 with these layers; "
                     "raise first_height or the number of layers");
  double lo = 1, hi = 10;
  for (int it = 0; it < 200 && hi - lo > 1e-15; ++it) {
    double mid = 0.5 * (lo + hi);
    (first(mid) > fraction ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// Frees a container's memory now (clear() keeps the capacity).
template <class C>
static void release(C& c) {
  C().swap(c);
}

// split_mesh; with `consume` (the same mesh as `in`), its node arrays are released once the new
// nodes' coordinates are computed and its pass-through blocks' connectivity is moved into the
// result: the stage then never holds the input's nodes beside the whole output (its peak).
static Result split_impl(const Mesh& in, Mesh* consume, const Options& opt, int threads) {
  if (opt.layers < 1 || opt.layers > 100) throw StageError("split: layers must be in [1, 100]");
  if (!(opt.ratio >= 1 && opt.ratio <= 10)) throw StageError("split: ratio must be in [1, 10]");
  if (in.dimension() != 3)
    throw StageError("split: the input mesh has no volume elements (dimension " + std::to_string(in.dimension()) +
                     "); split needs a 3D near-field mesh of prisms and hexes");
  const int P = in.order();
  for (auto& b : in.blocks) {
    int dim = model::dimension(b.shape);
    if (dim >= 1 && b.size() > 0 && b.order != P)
      throw StageError("split: order mismatch: a block of " + std::to_string(b.size()) + " " +
                       model::shape_name(b.shape) + " elements of order " + std::to_string(b.order) + " on entity (" +
                       std::to_string(b.entity_dim) + ", " + std::to_string(b.entity_tag) +
                       ") in a mesh of order " + std::to_string(P) + "; curve all elements to one order first");
  }

  // wall faces
  auto is_wall_entity = [&](int dim, int tag) {
    const model::Entity* e = in.find_entity(dim, tag);
    if (!e) return false;
    for (int p : e->physicals)
      for (auto& g : in.physicals)
        if (g.dim == dim && g.tag == p && g.name == opt.wall_group) return true;
    return false;
  };
  std::unordered_set<FaceKey, FaceKeyHash> walls;
  // boundary faces (any 2D element) -> entity tag (the first in mesh order)
  std::unordered_map<FaceKey, int, FaceKeyHash> bfaces;
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> bedges;  // edges of boundary faces -> entity
  for (auto& b : in.blocks) {
    if (model::dimension(b.shape) != 2) continue;
    int nv = model::num_vertices(b.shape);
    bool wall = is_wall_entity(b.entity_dim, b.entity_tag);
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* en = b.element(e);
      FaceKey k = face_key(en, nv);
      bfaces.emplace(k, b.entity_tag);
      if (wall) walls.insert(k);
      for (auto [a, c] : model::edge_vertices(b.shape))
        bedges.emplace(std::make_pair(std::min(en[a], en[c]), std::max(en[a], en[c])), b.entity_tag);
    }
  }
  if (walls.empty())
    throw StageError("split: the mesh has no wall faces (no boundary face in the physical group '" + opt.wall_group +
                     "'); split subdivides the macro elements towards their wall faces");

  // macro elements and their patterns
  Result res;
  Stats& st = res.stats;
  st.layers = opt.layers;
  st.order = P;
  std::vector<Macro> macros;
  std::map<std::array<int, 4>, int> pattern_of;  // (shape, dirsplit[3]) -> pattern
  std::vector<std::array<int, 4>> pattern_keys;
  for (std::uint32_t bi = 0; bi < in.blocks.size(); ++bi) {
    const ElementBlock& b = in.blocks[bi];
    if (model::dimension(b.shape) != 3) continue;
    if (b.shape != Shape::Prism && b.shape != Shape::Hex) {
      st.passthrough_elements += b.size();
      continue;
    }
    const auto& faces = model::face_vertices(b.shape);
    for (std::uint32_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* en = b.element(e);
      bool on[6] = {};
      for (std::size_t f = 0; f < faces.size(); ++f) {
        std::uint32_t v[4];
        for (std::size_t i = 0; i < faces[f].size(); ++i) v[i] = en[faces[f][i]];
        on[f] = walls.count(face_key(v, int(faces[f].size()))) > 0;
      }
      auto elem_name = [&]() {
        std::ostringstream s;
        s << model::shape_name(b.shape) << " " << (b.tags.empty() ? e + 1 : b.tags[e]) << " of volume "
          << b.entity_tag << " (first vertex at " << where(in, en[0]) << ")";
        return s.str();
      };
      int ds[3] = {0, 0, 0}, walls_n = 0;
      if (b.shape == Shape::Prism) {
        if (on[0] && on[1])
          throw StageError("split: " + elem_name() + " has both triangular faces on a wall; a boundary-layer prism has exactly one");
        if (!on[0] && !on[1])
          throw StageError("split: " + elem_name() + " has no triangular face on a wall ('" + opt.wall_group +
                           "'): it is not a boundary-layer macro prism (split expects the one-layer near-field mesh of the sweep stage)");
        ds[2] = on[0] ? -1 : 1;
        walls_n = 1;
        ++st.macro_prisms;
      } else {
        for (int f = 0; f < 6; ++f) {
          if (!on[f]) continue;
          auto [d, s] = hex_face_dir(f);
          if (ds[d] != 0)
            throw StageError("split: " + elem_name() + " has two opposite faces on walls; a junction hex has its wall faces on distinct axes");
          ds[d] = s ? 1 : -1;
          ++walls_n;
        }
        if (walls_n == 0)
          throw StageError("split: " + elem_name() + " has no face on a wall ('" + opt.wall_group +
                           "'): it is not a boundary-layer macro hex");
        (walls_n == 1 ? st.macro_hexes_1wall : walls_n == 2 ? st.macro_hexes_2wall : st.macro_hexes_3wall)++;
      }
      std::array<int, 4> key{int(b.shape), ds[0], ds[1], ds[2]};
      auto [it, ins] = pattern_of.emplace(key, int(pattern_keys.size()));
      if (ins) pattern_keys.push_back(key);
      macros.push_back({bi, e, it->second, walls_n});
    }
  }
  if (macros.empty())
    throw StageError("split: the mesh has no prisms or hexes: nothing to split (the near-field macro elements come from the sweep stage)");

  int nthreads = threads > 0 ? threads : tbb::this_task_arena::max_concurrency();
  tbb::task_arena arena(nthreads);
  auto par = [&](std::size_t n, auto&& body) {
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) body(i);
      });
    });
  };
  auto gather = [&](const Macro& mc, std::vector<double>& X) {
    const ElementBlock& b = in.blocks[mc.block];
    const std::uint32_t* en = b.element(mc.elem);
    int n = b.nodes_per_element();
    X.resize(3 * std::size_t(n));
    for (int i = 0; i < n; ++i) X[3 * i] = in.x[en[i]], X[3 * i + 1] = in.y[en[i]], X[3 * i + 2] = in.z[en[i]];
  };
  auto dirs_of = [&](const Macro& mc) { return pattern_keys[mc.pattern]; };

  // thickness of every stack (per split direction), then the ratio
  // the normal lines of each pattern's split directions, to t1 (nullptr: direction not split)
  auto normal_lines = [&](double t1) {
    std::vector<std::array<std::unique_ptr<NormalLine>, 3>> lines(pattern_keys.size());
    for (std::size_t p = 0; p < pattern_keys.size(); ++p)
      for (int d = 0; d < 3; ++d)
        if (pattern_keys[p][1 + d]) lines[p][d] = std::make_unique<NormalLine>(Shape(pattern_keys[p][0]), P, d, pattern_keys[p][1 + d], t1);
    return lines;
  };
  std::vector<std::array<double, 3>> thick(macros.size(), {0, 0, 0});
  {
    const auto lines = normal_lines(1.0);
    par(macros.size(), [&](std::size_t i) {
      thread_local std::vector<double> X;
      gather(macros[i], X);
      for (int d = 0; d < 3; ++d)
        if (const auto& l = lines[macros[i].pattern][d]) thick[i][d] = l->length(X.data());
    });
  }
  double tmin = INFINITY, tmax = 0;
  for (std::size_t i = 0; i < macros.size(); ++i)
    for (int d = 0; d < 3; ++d)
      if (dirs_of(macros[i])[1 + d]) tmin = std::min(tmin, thick[i][d]), tmax = std::max(tmax, thick[i][d]);
  st.thickness_min = tmin, st.thickness_max = tmax;
  double ratio = opt.ratio;
  if (opt.first_height > 0 && !(tmax > 0))
    throw StageError("split: first_height is given but the stacks have no thickness");
  if (opt.first_height > 0) {
    ratio = ratio_for_first_fraction(opt.layers, opt.first_height / tmax);
    st.ratio_from_first_height = true;
  }
  st.ratio = ratio;
  const std::vector<double> cuts = layer_cuts(opt.layers, ratio);
  std::vector<double> firsth(macros.size() * 3, NAN);
  {
    const auto lines = normal_lines(cuts[1]);
    par(macros.size(), [&](std::size_t i) {
      thread_local std::vector<double> X;
      gather(macros[i], X);
      for (int d = 0; d < 3; ++d)
        if (const auto& l = lines[macros[i].pattern][d]) firsth[3 * i + d] = l->length(X.data());
    });
  }
  st.first_height_min = INFINITY;
  for (double h : firsth)
    if (!std::isnan(h)) st.first_height_min = std::min(st.first_height_min, h), st.first_height_max = std::max(st.first_height_max, h);

  std::vector<Pattern> patterns;
  for (auto& k : pattern_keys) {
    int ds[3] = {k[1], k[2], k[3]};
    patterns.push_back(make_pattern(Shape(k[0]), P, opt.layers, ds, cuts));
  }

  // the first macro element of each block (SIZE_MAX: none)
  std::vector<std::size_t> first_macro(in.blocks.size(), SIZE_MAX);
  for (std::size_t i = macros.size(); i-- > 0;) first_macro[macros[i].block] = i;
  // The conformity check's expectation, from the input's topology (built and dropped here, before
  // the output exists): every boundary face of the input becomes its sub-faces, every interior
  // face stays interior
  std::size_t expect_boundary = 0, nc_in = 0;
  if (opt.check_conformity) {
    const model::Topology tin = model::build_topology(in);
    nc_in = tin.nonconforming_faces;
    for (auto& f : tin.faces) {
      if (f.elements.size() != 1) continue;
      const ElementRef& r = f.elements[0];
      std::size_t mi = first_macro[r.block] == SIZE_MAX ? SIZE_MAX : first_macro[r.block] + r.element;
      if (mi == SIZE_MAX) {
        ++expect_boundary;
        continue;
      }
      const Pattern& pt = patterns[macros[mi].pattern];
      expect_boundary += pt.face_split[r.local] ? pt.face_subs[r.local].size() : 1;
    }
  }

  // numbering (serial, mesh order): reused original nodes, keyed shared points, interiors
  const std::uint32_t n0 = std::uint32_t(in.num_nodes());
  std::vector<std::size_t> foff(macros.size() + 1, 0);
  for (std::size_t i = 0; i < macros.size(); ++i) foff[i + 1] = foff[i] + patterns[macros[i].pattern].pts.size();
  std::vector<std::uint32_t> fid(foff.back());
  std::vector<std::uint8_t> owner(foff.back(), 0);
  SharedPoints keyed;
  std::uint64_t next = n0;
  for (std::size_t i = 0; i < macros.size(); ++i) {
    const Pattern& pt = patterns[macros[i].pattern];
    const std::uint32_t* en = in.blocks[macros[i].block].element(macros[i].elem);
    for (std::size_t q = 0; q < pt.pts.size(); ++q) {
      const FinePoint& fp = pt.pts[q];
      std::uint32_t id;
      if (fp.loc == Loc::Reuse) {
        id = en[fp.reuse];
      } else if (fp.loc == Loc::Interior) {
        id = std::uint32_t(next++);
        owner[foff[i] + q] = 1;
      } else {
        std::uint32_t& at = keyed.slot(make_key(fp, en));
        if (at == kNone) at = std::uint32_t(next++), owner[foff[i] + q] = 1;
        id = at;
      }
      fid[foff[i] + q] = id;
    }
  }
  if (next >= kNone) throw StageError("split: the split mesh would have more than 2^32 - 1 nodes; use fewer layers");
  const std::size_t ntot = std::size_t(next);
  st.new_nodes = ntot - n0;

  // coordinates (and classification) of the new nodes, in parallel into their slots
  Mesh& out = res.mesh;
  out.entities = in.entities;
  out.physicals = in.physicals;
  const bool classified = !in.node_entity_dim.empty();
  const bool params = in.has_parametric();
  // each node array: the input's (original indices), then room for the new nodes; a consumed
  // input's array is released as soon as it is copied (the two are never held whole together).
  // From here the input's nodes are read from the output.
  auto extend = [&](auto& dst, auto Mesh::*member, auto fill) {
    const auto& src = in.*member;
    dst.reserve(ntot);
    dst.assign(src.begin(), src.end());
    if (consume) release(consume->*member);
    dst.resize(ntot, fill);
  };
  extend(out.x, &Mesh::x, 0.0), extend(out.y, &Mesh::y, 0.0), extend(out.z, &Mesh::z, 0.0);
  if (classified) extend(out.node_entity_dim, &Mesh::node_entity_dim, 3), extend(out.node_entity_tag, &Mesh::node_entity_tag, 0);
  if (params) extend(out.node_u, &Mesh::node_u, double(NAN)), extend(out.node_v, &Mesh::node_v, double(NAN));
  const int C = params ? 5 : 3;
  par(macros.size(), [&](std::size_t i) {
    const Macro& mc = macros[i];
    const Pattern& pt = patterns[mc.pattern];
    const ElementBlock& b = in.blocks[mc.block];
    const std::uint32_t* en = b.element(mc.elem);
    const int n = b.nodes_per_element(), P1 = P + 1;
    thread_local std::vector<double> Xn, A, S1, S2, F;
    Xn.assign(std::size_t(n) * C, 0.0);
    for (int k = 0; k < n; ++k) {
      std::uint32_t g = en[k];
      Xn[k * C] = out.x[g], Xn[k * C + 1] = out.y[g], Xn[k * C + 2] = out.z[g];
      if (params) {
        double u = out.node_u[g], v = out.node_v[g];
        Xn[k * C + 3] = std::isnan(u) ? 0 : u, Xn[k * C + 4] = std::isnan(v) ? 0 : v;
      }
    }
    F.assign(pt.pts.size() * C, 0.0);
    if (pt.shape == Shape::Prism) {
      const int NK = pt.N[2] + 1;
      for (int j = 0; j <= P; ++j)
        for (int ii = 0; ii + j <= P; ++ii)
          for (int K = 0; K < NK; ++K) {
            double* o = &F[pt.index(ii, j, K) * C];
            const double* tk = &pt.tab[2][std::size_t(K) * P1];
            for (int k = 0; k <= P; ++k) {
              double w = tk[k];
              if (w == 0) continue;
              const double* xv = &Xn[std::size_t(pt.lat_index[ii + P1 * (j + P1 * k)]) * C];
              for (int c = 0; c < C; ++c) o[c] += w * xv[c];
            }
          }
    } else {
      const int N0 = pt.N[0] + 1, N1 = pt.N[1] + 1, N2 = pt.N[2] + 1;
      A.assign(std::size_t(P1) * P1 * P1 * C, 0.0);
      for (int k = 0; k < P1; ++k)
        for (int j = 0; j < P1; ++j)
          for (int ii = 0; ii < P1; ++ii) {
            const double* xv = &Xn[std::size_t(pt.lat_index[ii + P1 * (j + P1 * k)]) * C];
            std::copy(xv, xv + C, &A[((std::size_t(k) * P1 + j) * P1 + ii) * C]);
          }
      S1.assign(std::size_t(N0) * P1 * P1 * C, 0.0);  // [k][j][I]
      for (int k = 0; k < P1; ++k)
        for (int j = 0; j < P1; ++j)
          for (int I = 0; I < N0; ++I) {
            double* o = &S1[((std::size_t(k) * P1 + j) * N0 + I) * C];
            for (int ii = 0; ii < P1; ++ii) {
              double w = pt.tab[0][std::size_t(I) * P1 + ii];
              if (w == 0) continue;
              const double* a = &A[((std::size_t(k) * P1 + j) * P1 + ii) * C];
              for (int c = 0; c < C; ++c) o[c] += w * a[c];
            }
          }
      S2.assign(std::size_t(N0) * N1 * P1 * C, 0.0);  // [k][J][I]
      for (int k = 0; k < P1; ++k)
        for (int J = 0; J < N1; ++J)
          for (int j = 0; j < P1; ++j) {
            double w = pt.tab[1][std::size_t(J) * P1 + j];
            if (w == 0) continue;
            for (int I = 0; I < N0; ++I) {
              double* o = &S2[((std::size_t(k) * N1 + J) * N0 + I) * C];
              const double* a = &S1[((std::size_t(k) * P1 + j) * N0 + I) * C];
              for (int c = 0; c < C; ++c) o[c] += w * a[c];
            }
          }
      for (int K = 0; K < N2; ++K)
        for (int k = 0; k < P1; ++k) {
          double w = pt.tab[2][std::size_t(K) * P1 + k];
          if (w == 0) continue;
          for (int J = 0; J < N1; ++J)
            for (int I = 0; I < N0; ++I) {
              double* o = &F[pt.index(I, J, K) * C];
              const double* a = &S2[((std::size_t(k) * N1 + J) * N0 + I) * C];
              for (int c = 0; c < C; ++c) o[c] += w * a[c];
            }
        }
    }
    // classification of this element's faces and edges (for the nodes it owns)
    const auto& fverts = model::face_vertices(pt.shape);
    const auto& fnodes = model::face_nodes(pt.shape, P);
    const auto& enodes = model::edge_nodes(pt.shape, P);
    auto all_on = [&](const std::vector<int>& nodes, int dim, int tag) {
      if (!params) return false;
      for (int k : nodes) {
        std::uint32_t g = en[k];
        if (out.node_entity_dim[g] != dim || out.node_entity_tag[g] != tag || std::isnan(out.node_u[g]) ||
            (dim == 2 && std::isnan(out.node_v[g])))
          return false;
      }
      return true;
    };
    int fent[6], eent_dim[12], eent_tag[12];
    bool fpar[6] = {}, epar[12] = {};
    if (classified) {
      for (std::size_t f = 0; f < fverts.size(); ++f) {
        std::uint32_t v[4];
        for (std::size_t k = 0; k < fverts[f].size(); ++k) v[k] = en[fverts[f][k]];
        auto it = bfaces.find(face_key(v, int(fverts[f].size())));
        fent[f] = it == bfaces.end() ? -1 : it->second;
        if (fent[f] >= 0) fpar[f] = all_on(fnodes[f], 2, fent[f]);
      }
      const auto& ev = model::edge_vertices(pt.shape);
      for (std::size_t e = 0; e < ev.size(); ++e) {
        eent_dim[e] = 3, eent_tag[e] = b.entity_tag;
        const auto& en_e = enodes[e];
        bool consistent = en_e.size() > 2;
        for (std::size_t k = 2; k < en_e.size() && consistent; ++k) {
          std::uint32_t g = en[en_e[k]], g2 = en[en_e[2]];
          consistent = out.node_entity_dim[g] == out.node_entity_dim[g2] && out.node_entity_tag[g] == out.node_entity_tag[g2] &&
                       out.node_entity_dim[g] <= 2;
        }
        if (consistent) {
          eent_dim[e] = out.node_entity_dim[en[en_e[2]]], eent_tag[e] = out.node_entity_tag[en[en_e[2]]];
          epar[e] = all_on(en_e, eent_dim[e], eent_tag[e]);
        } else {
          // an edge on a boundary face (of this element or of another one): that face's entity
          std::uint32_t a = en[ev[e][0]], c = en[ev[e][1]];
          auto it = bedges.find({std::min(a, c), std::max(a, c)});
          if (it != bedges.end()) {
            eent_dim[e] = 2, eent_tag[e] = it->second;
            epar[e] = all_on(en_e, 2, it->second);
          }
        }
      }
    }
    for (std::size_t q = 0; q < pt.pts.size(); ++q) {
      if (!owner[foff[i] + q]) continue;
      std::uint32_t id = fid[foff[i] + q];
      const double* o = &F[q * C];
      out.x[id] = o[0], out.y[id] = o[1], out.z[id] = o[2];
      if (!classified) continue;
      const FinePoint& fp = pt.pts[q];
      int dim = 3, tag = b.entity_tag;
      bool par = false;
      if (fp.loc == Loc::Face && fent[fp.mface] >= 0) dim = 2, tag = fent[fp.mface], par = fpar[fp.mface];
      if (fp.loc == Loc::Edge) dim = eent_dim[fp.medge], tag = eent_tag[fp.medge], par = epar[fp.medge];
      out.node_entity_dim[id] = dim, out.node_entity_tag[id] = tag;
      if (params && par) out.node_u[id] = o[3], out.node_v[id] = dim == 2 ? o[4] : NAN;
    }
  });
  if (params)
    for (std::size_t id = n0; id < ntot; ++id)
      if (out.node_entity_dim[id] <= 2 && std::isnan(out.node_u[id])) ++st.nodes_without_params;
  release(owner);  // only the coordinates needed it

  // periodic links: new nodes of split slave faces -> the same keys on the master side
  // A face's own link lists the nodes classified on the face; the vertices of a split face on
  // the face's boundary (a layer edge on a CAD edge, a corner on a CAD vertex) have their
  // masters in the links of those edges and vertices (Rotor 67: the periodic side's corner at
  // the inlet and the hub), so the masters are looked up in every link.
  std::unordered_map<std::uint32_t, std::uint32_t> master;
  for (const auto& link : in.periodic)
    for (auto [s, m] : link.nodes) master.emplace(s, m);
  std::vector<model::PeriodicLink> periodic = in.periodic;
  for (auto& link : periodic) {
    if (link.dim != 2) continue;
    std::vector<std::pair<std::uint32_t, std::uint32_t>> add;
    for (std::size_t i = 0; i < macros.size(); ++i) {
      const Pattern& pt = patterns[macros[i].pattern];
      const std::uint32_t* en = in.blocks[macros[i].block].element(macros[i].elem);
      const auto& fverts = model::face_vertices(pt.shape);
      for (std::size_t f = 0; f < fverts.size(); ++f) {
        if (!pt.face_split[f]) continue;
        std::uint32_t v[4];
        for (std::size_t k = 0; k < fverts[f].size(); ++k) v[k] = en[fverts[f][k]];
        auto it = bfaces.find(face_key(v, int(fverts[f].size())));
        if (it == bfaces.end() || it->second != link.tag) continue;
        std::uint32_t gv[8];
        int nv = model::num_vertices(pt.shape);
        for (int k = 0; k < nv; ++k) {
          auto m = master.find(en[k]);
          gv[k] = m == master.end() ? en[k] : m->second;
        }
        for (int k : fverts[f])
          if (!master.count(en[k]))
            throw StageError("split: periodic surface " + std::to_string(link.tag) + ": the vertex at " + where(out, en[k]) +
                             " of a split face has no master node; cannot extend the periodic link to the new nodes");
        for (std::uint32_t q : pt.face_pts[f]) {
          const std::uint32_t m = keyed.find(make_key(pt.pts[q], gv));
          if (m == kNone)
            throw StageError("split: periodic surface " + std::to_string(link.tag) + " (master " + std::to_string(link.master_tag) +
                             "): the master face of the split face at " + where(out, en[fverts[f][0]]) +
                             " is not split the same way (is it a wall stack with the same wall?)");
          add.emplace_back(fid[foff[i] + q], m);
        }
      }
    }
    std::sort(add.begin(), add.end());
    add.erase(std::unique(add.begin(), add.end()), add.end());
    st.periodic_pairs_added += add.size();
    link.nodes.insert(link.nodes.end(), add.begin(), add.end());
  }

  // element blocks
  std::unordered_map<FaceKey, std::pair<std::uint32_t, int>, FaceKeyHash> split_faces;  // -> (macro, face)
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<std::uint32_t, std::uint32_t>> split_edges;  // -> (flag wrt lo, N)
  for (std::uint32_t i = 0; i < macros.size(); ++i) {
    const Pattern& pt = patterns[macros[i].pattern];
    const std::uint32_t* en = in.blocks[macros[i].block].element(macros[i].elem);
    const auto& fverts = model::face_vertices(pt.shape);
    for (std::size_t f = 0; f < fverts.size(); ++f) {
      if (!pt.face_split[f]) continue;
      std::uint32_t v[4];
      for (std::size_t k = 0; k < fverts[f].size(); ++k) v[k] = en[fverts[f][k]];
      split_faces.emplace(face_key(v, int(fverts[f].size())), std::make_pair(i, int(f)));
    }
    for (const EdgeDesc& e : pt.split_edges) {
      std::uint32_t k[5];
      edge_key(e, en, k);
      split_edges.emplace(std::make_pair(k[0], k[1]), std::make_pair(k[2], k[3]));
    }
  }
  for (std::size_t bi = 0; bi < in.blocks.size(); ++bi) {
    const ElementBlock& b = in.blocks[bi];
    ElementBlock nb;
    nb.shape = b.shape, nb.order = b.order, nb.entity_dim = b.entity_dim, nb.entity_tag = b.entity_tag;
    const int dim = model::dimension(b.shape);
    if (first_macro[bi] != SIZE_MAX) {
      std::size_t total = 0;
      for (std::size_t i = first_macro[bi]; i < macros.size() && macros[i].block == bi; ++i)
        total += std::size_t(patterns[macros[i].pattern].nsub) * patterns[macros[i].pattern].nps;
      nb.nodes.reserve(total);
      for (std::size_t i = first_macro[bi]; i < macros.size() && macros[i].block == bi; ++i) {
        const Pattern& pt = patterns[macros[i].pattern];
        for (std::size_t s = 0; s < std::size_t(pt.nsub) * pt.nps; ++s) nb.nodes.push_back(fid[foff[i] + pt.sub_nodes[s]]);
        (b.shape == Shape::Prism ? st.sub_prisms : st.sub_hexes) += pt.nsub;
      }
    } else if (dim == 2) {
      const int nv = model::num_vertices(b.shape);
      std::vector<int> rev = reversal(b.shape, P);
      for (std::size_t e = 0; e < b.size(); ++e) {
        const std::uint32_t* ev = b.element(e);
        auto it = split_faces.find(face_key(ev, nv));
        if (it == split_faces.end()) {
          nb.add(ev);
          continue;
        }
        auto [mi, f] = it->second;
        const Pattern& pt = patterns[macros[mi].pattern];
        const std::uint32_t* en = in.blocks[macros[mi].block].element(macros[mi].elem);
        const auto& fv = model::face_vertices(pt.shape)[f];
        if (int(fv.size()) != nv) throw StageError("split: internal error: boundary face shape differs from the macro face");
        int r = 0;
        while (r < nv && en[fv[r]] != ev[0]) ++r;
        bool same = r < nv && en[fv[(r + 1) % nv]] == ev[1];
        bool reversed = r < nv && en[fv[(r + nv - 1) % nv]] == ev[1];
        if (!same && !reversed)
          throw StageError("split: the boundary face at " + where(out, ev[0]) + " does not match its macro element's face");
        const auto& fn = model::face_nodes(pt.shape, P)[f];
        std::vector<std::uint32_t> sub(fn.size()), outn(fn.size());
        for (int s : pt.face_subs[f]) {
          for (std::size_t k = 0; k < fn.size(); ++k) sub[k] = fid[foff[mi] + pt.sub_nodes[std::size_t(s) * pt.nps + fn[k]]];
          if (reversed)
            for (std::size_t k = 0; k < fn.size(); ++k) outn[k] = sub[rev[k]];
          nb.add((reversed ? outn : sub).data());
          ++st.boundary_subfaces;
        }
        ++st.boundary_faces_split;
      }
    } else if (dim == 1) {
      for (std::size_t e = 0; e < b.size(); ++e) {
        const std::uint32_t* ev = b.element(e);
        std::uint32_t lo = std::min(ev[0], ev[1]), hi = std::max(ev[0], ev[1]);
        auto it = split_edges.find({lo, hi});
        if (it == split_edges.end()) {
          nb.add(ev);
          continue;
        }
        // Plain copies, not a structured binding: clang 14 (make fuzz) cannot capture bindings.
        const auto flag = it->second.first;
        const auto N = it->second.second;
        auto node_at = [&](std::uint32_t o) -> std::uint32_t {  // offset from ev[0]
          if (o == 0) return ev[0];
          if (o == N) return ev[1];
          Key k;
          k.fill(kNone);
          k[0] = 1, k[1] = lo, k[2] = hi, k[3] = flag, k[4] = N, k[5] = ev[0] == lo ? o : N - o;
          const std::uint32_t m = keyed.find(k);
          if (m == kNone) throw StageError("split: internal error: a split CAD line has no sub-node");
          return m;
        };
        std::vector<std::uint32_t> ln(P + 1);
        for (std::uint32_t s = 0; s < N / std::uint32_t(P); ++s) {
          ln[0] = node_at(s * P), ln[1] = node_at((s + 1) * P);
          for (int k = 1; k < P; ++k) ln[1 + k] = node_at(s * P + k);
          nb.add(ln.data());
        }
        ++st.lines_split;
      }
    } else {
      if (consume) nb.nodes = std::move(consume->blocks[bi].nodes);  // in's block is not read again
      else nb.nodes = b.nodes;
    }
    res.passed_through.push_back(first_macro[bi] == SIZE_MAX && dim == 3);
    out.blocks.push_back(std::move(nb));
  }

  // The numbering's maps and the per-macro fine-point ids are done with: release them before
  // the compaction and the conformity check, which then hold the output mesh, the input (unless
  // consumed) and one topology (the stage's peak memory)
  keyed = SharedPoints();
  release(fid), release(walls), release(bfaces), release(bedges);
  release(split_faces), release(split_edges), release(master);
  if (consume) release(consume->blocks);  // the input is not read again (its topology was counted first)

  // drop the nodes no element uses any more (the original high-order nodes inside split
  // edges, faces and volumes); keep the order of the others
  std::vector<std::uint32_t> newid(ntot, kNone);
  for (auto& b : out.blocks)
    for (auto n : b.nodes) newid[n] = 0;
  std::uint32_t c = 0, kept_originals = 0;
  for (std::size_t n = 0; n < ntot; ++n)
    if (newid[n] == 0) newid[n] = c++;
  for (std::size_t n = 0; n < n0; ++n) kept_originals += newid[n] != kNone;
  auto compact = [&](auto& v) {
    if (v.empty()) return;
    for (std::size_t n = 0; n < ntot; ++n)
      if (newid[n] != kNone) v[newid[n]] = v[n];
    v.resize(c);
  };
  compact(out.x), compact(out.y), compact(out.z);
  compact(out.node_entity_dim), compact(out.node_entity_tag), compact(out.node_u), compact(out.node_v);
  for (auto& b : out.blocks)
    for (auto& n : b.nodes) n = newid[n];
  for (auto& link : periodic) {
    std::vector<std::pair<std::uint32_t, std::uint32_t>> kept;
    for (auto [s, m] : link.nodes)
      if (newid[s] != kNone && newid[m] != kNone) kept.emplace_back(newid[s], newid[m]);
    link.nodes = std::move(kept);
  }
  out.periodic = std::move(periodic);
  st.nodes_in = n0, st.nodes_out = c, st.dropped_nodes = ntot - c;
  release(newid);
  // the dropped nodes' room (Rotor 67: 1.2 M nodes, 60 MB) freed before the topology is built;
  // one array at a time, after newid, as each shrink copies its array
  for (auto* v : {&out.x, &out.y, &out.z, &out.node_u, &out.node_v}) v->shrink_to_fit();
  out.node_entity_dim.shrink_to_fit(), out.node_entity_tag.shrink_to_fit();

  if (opt.check_conformity) {
    // every boundary face of the input becomes its sub-faces, every interior face stays
    // interior: a split face whose neighbour splits it differently would show up as extra
    // boundary faces (hanging nodes), not as a non-conforming pair
    model::Topology t = model::build_topology(out);
    if (t.boundary_faces != expect_boundary) {
      std::string at;
      for (auto& f : t.faces)
        if (f.elements.size() == 1 && f.num_vertices > 0) {
          bool fresh = false;
          for (int k = 0; k < f.num_vertices; ++k) fresh = fresh || f.vertices[k] >= kept_originals;
          if (fresh) {
            at = where(out, f.vertices[0]);
            break;
          }
        }
      throw StageError("split: the split mesh is non-conforming: it has " + std::to_string(t.boundary_faces) +
                       " boundary faces where " + std::to_string(expect_boundary) +
                       " were expected (hanging nodes between neighbouring stacks, e.g. near " + at +
                       "): a face shared by two macro elements is subdivided differently on its two sides "
                       "(neighbouring stacks with their walls on different sides, or a split face of a junction hex "
                       "shared with a pyramid or an unsplit element)");
    }
    if (t.nonconforming_faces > nc_in) {
      std::string at;
      for (auto& f : t.faces)
        if (!f.conforming) {
          at = where(out, f.vertices[0]);
          break;
        }
      throw StageError("split: the split mesh has " + std::to_string(t.nonconforming_faces) +
                       " non-conforming faces (the input had " + std::to_string(nc_in) + "), the first at " + at +
                       ": a subdivided face of a macro element is shared with an element that does not subdivide it the same way "
                       "(e.g. a pyramid or tet on a split face of a junction hex, or neighbouring stacks with different walls)");
    }
  }
  try {
    out.check();
  } catch (const std::exception& e) {
    throw StageError(std::string("split: internal error, inconsistent result: ") + e.what());
  }
  return res;
}

Result split_mesh(const Mesh& in, const Options& opt, int threads) { return split_impl(in, nullptr, opt, threads); }
Result split_mesh(Mesh&& in, const Options& opt, int threads) { return split_impl(in, &in, opt, threads); }

}  // namespace meshflow::split
