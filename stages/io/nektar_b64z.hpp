// Internal: Nektar++'s compressed XML sections (COMPRESSED="B64Z-LittleEndian", BITSIZE="64").
// A section's text is base64 of the zlib stream of an array of fixed-size records, Nektar++'s
// POD structs of SpatialDomains/MeshEntities.hpp (NekInt64 ids, double coordinates; 64-bit
// ints in every release since the format was introduced, so that the structs have no padding),
// little endian:
//   VERTEX        {id, x, y, z}                                  32 bytes
//   EDGE          {id, v0, v1}                                   24 bytes
//   FACE T / Q    {id, e[3]} / {id, e[4]}                        32 / 40 bytes
//   ELEMENT A/P/R/H {id, f[4]} / {id, f[5]} / {id, f[5]} / {id, f[6]}
//   CURVED E / F  {id, entityid, npoints, ptid, ptoffset, ptype} 48 bytes
//   CURVED DATAPOINTS: INDEX int64[], POINTS {id, x, y, z}[]; the points of curve i are
//                  POINTS[INDEX[ptoffset + j]], j < npoints.
// Nektar++ pads the zlib bytes with zeros to a multiple of 3 before base64, so its text has no
// '=' padding; we write the same and read both.
#pragma once

#include "stages/io/mesh_io.hpp"

#include <bit>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

namespace meshflow::io::nektar {

static_assert(std::endian::native == std::endian::little, "the B64Z-LittleEndian form is written as the host's bytes");

inline constexpr const char* kCompressed = "B64Z-LittleEndian";

struct Vertex {
  std::int64_t id;
  double x, y, z;
};
struct Edge {
  std::int64_t id, v0, v1;
};
template <int N>
struct Sides {  // faces (edge ids) and elements (face ids)
  std::int64_t id;
  std::int64_t s[N];
};
struct CurvedInfo {
  std::int64_t id, entityid, npoints, ptid, ptoffset, ptype;
};
static_assert(sizeof(Vertex) == 32 && sizeof(Edge) == 24 && sizeof(Sides<3>) == 32 && sizeof(Sides<4>) == 40 &&
              sizeof(Sides<5>) == 48 && sizeof(Sides<6>) == 56 && sizeof(CurvedInfo) == 48);

// Nektar++'s LibUtilities::PointsType values of the point sets we read and write (the enum of
// current Nektar++; releases before 5.0 had eNodalTriSPI before eNodalTriEvenlySpaced, which
// was then 25: read as such for triangle faces, where 25 cannot mean anything else).
enum PointsType : std::int64_t {
  kGaussLobattoLegendre = 4,
  kPolyEvenlySpaced = 17,
  kNodalTriElec = 22,
  kNodalTriEvenlySpaced = 24,
  kNodalTriEvenlySpacedPre5 = 25,
};

// zlib (level 1; a section larger than 1 MiB compressed in pieces in parallel, one stream) then
// base64 zero-padded to a multiple of 3 bytes, as Nektar++ writes it.
std::string encode(const void* data, std::size_t bytes);
template <class T>
std::string encode(const std::vector<T>& v) {
  return encode(v.data(), v.size() * sizeof(T));
}

// base64 then zlib; `where` ("file:line N: <VERTEX>") starts every error message. Throws
// MeshIOError for text that is not base64, a stream that is not zlib or is cut short.
std::string decode(std::string_view text, const std::string& where);
// decode into records of T: the byte count must be a whole number of records.
template <class T>
std::vector<T> decode_records(std::string_view text, const std::string& where, const char* record) {
  const std::string bytes = decode(text, where);
  if (bytes.size() % sizeof(T) != 0)
    throw MeshIOError(where + ": compressed data of " + std::to_string(bytes.size()) + " bytes is not a whole number of " +
                      record + " records of " + std::to_string(sizeof(T)) +
                      " bytes (a file of another BITSIZE or a corrupt section; rewrite it with NekMesh ...:xml:uncompress)");
  std::vector<T> out(bytes.size() / sizeof(T));
  if (!out.empty()) std::memcpy(out.data(), bytes.data(), bytes.size());
  return out;
}

}  // namespace meshflow::io::nektar
