// meshflow cad — one clone of a shape per thread, for parallel loops that project points on the
// CAD or classify them in its faces: those queries fill per-shape caches (cad.hpp's thread
// safety), so concurrent callers must not share one Shape. The clones share the geometry; each is
// made on its thread's first use. Header only (oneTBB): its users link TBB::tbb.
#pragma once

#include "stages/cad/cad.hpp"

#include <tbb/enumerable_thread_specific.h>

namespace meshflow::cad {

class ShapeClones {
 public:
  explicit ShapeClones(const Shape& s) : clones_([&s] { return s.clone(); }) {}  // s must outlive it
  // The calling thread's clone (const, for const callers: the clones are caches, not state).
  Shape& local() const { return clones_.local(); }

 private:
  mutable tbb::enumerable_thread_specific<Shape> clones_;
};

}  // namespace meshflow::cad
