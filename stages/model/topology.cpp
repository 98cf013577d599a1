#include "stages/model/topology.hpp"

#include <algorithm>
#include <limits>

namespace meshflow::model {

namespace {
struct Rec {
  std::array<std::uint32_t, 4> key;
  ElementRef ref;
  int nv;
  bool operator<(const Rec& o) const {
    if (key != o.key) return key < o.key;
    if (ref.block != o.ref.block) return ref.block < o.ref.block;
    if (ref.element != o.ref.element) return ref.element < o.ref.element;
    return ref.local < o.ref.local;
  }
};

// Local nodes of side `f` of an element: faces for 3D shapes, edges for 2D shapes.
const std::vector<int>& side_nodes(Shape s, int order, int f) {
  return dimension(s) == 3 ? face_nodes(s, order)[f] : edge_nodes(s, order)[f];
}
}  // namespace

Topology build_topology(const Mesh& m) {
  Topology t;
  t.dim = m.dimension();
  if (t.dim < 2) return t;
  const std::uint32_t none = std::numeric_limits<std::uint32_t>::max();
  // Every vector is sized before it is filled: growing by doubling held up to three times a
  // vector's size while it moved (the split stage's peak memory on order-4 meshes of millions
  // of nodes is the mesh plus this topology; issue 24 item 4)
  std::size_t nrecs = 0, nedges = 0;
  for (const auto& b : m.blocks) {
    if (dimension(b.shape) != t.dim) continue;
    nrecs += b.size() * (t.dim == 3 ? face_vertices(b.shape).size() : edge_vertices(b.shape).size());
    nedges += b.size() * edge_vertices(b.shape).size();
  }
  std::vector<Rec> recs;
  std::vector<std::array<std::uint32_t, 2>> edges;
  recs.reserve(nrecs);
  edges.reserve(nedges);
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    if (dimension(b.shape) != t.dim) continue;
    const int nsides = t.dim == 3 ? (int)face_vertices(b.shape).size() : (int)edge_vertices(b.shape).size();
    for (std::uint32_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* n = b.element(e);
      for (int f = 0; f < nsides; ++f) {
        Rec r{{none, none, none, none}, {bi, e, (std::uint32_t)f}, 0};
        if (t.dim == 3) {
          const auto& fv = face_vertices(b.shape)[f];
          for (size_t k = 0; k < fv.size(); ++k) r.key[k] = n[fv[k]];
          r.nv = (int)fv.size();
        } else {
          auto ev = edge_vertices(b.shape)[f];
          r.key[0] = n[ev[0]];
          r.key[1] = n[ev[1]];
          r.nv = 2;
        }
        std::sort(r.key.begin(), r.key.begin() + r.nv);
        recs.push_back(r);
      }
      for (auto ev : edge_vertices(b.shape)) {
        std::uint32_t a = n[ev[0]], c = n[ev[1]];
        edges.push_back({std::min(a, c), std::max(a, c)});
      }
    }
  }
  std::sort(recs.begin(), recs.end());
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  t.edges.assign(edges.begin(), edges.end());  // exactly sized, unlike the vector erase() shortened
  std::vector<std::array<std::uint32_t, 2>>().swap(edges);
  std::size_t nfaces = 0;
  for (size_t i = 0; i < recs.size(); ++i) nfaces += i == 0 || recs[i].key != recs[i - 1].key;
  t.faces.reserve(nfaces);
  std::vector<std::uint32_t> s[2];
  for (size_t i = 0; i < recs.size();) {
    size_t j = i;
    while (j < recs.size() && recs[j].key == recs[i].key) ++j;
    TopoFace f;
    f.vertices = recs[i].key;
    f.num_vertices = recs[i].nv;
    f.elements.reserve(j - i);
    for (size_t k = i; k < j; ++k) f.elements.push_back(recs[k].ref);
    if (f.elements.size() > 2) f.conforming = false;
    if (f.elements.size() == 2) {
      for (int k = 0; k < 2; ++k) {
        const auto& r = f.elements[k];
        const auto& b = m.blocks[r.block];
        const std::uint32_t* n = b.element(r.element);
        s[k].clear();
        for (int ln : side_nodes(b.shape, b.order, (int)r.local)) s[k].push_back(n[ln]);
        std::sort(s[k].begin(), s[k].end());
      }
      if (s[0] != s[1]) f.conforming = false;
    }
    if (f.elements.size() == 1) ++t.boundary_faces;
    if (!f.conforming) ++t.nonconforming_faces;
    t.faces.push_back(std::move(f));
    i = j;
  }
  return t;
}

}  // namespace meshflow::model
