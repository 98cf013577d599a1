// Nektar++'s B64Z codec: zlib for the compression (the library Nektar++ itself uses, so the
// streams are the same) and OpenSSL's EVP_EncodeBlock / EVP_DecodeBlock for base64 (OpenSSL is
// already linked for the engine's hashes, and neither zlib nor expat has base64; a coder of our
// own would be one more thing to get wrong at a chunk boundary).
#include "stages/io/nektar_b64z.hpp"

#include <openssl/evp.h>
#include <zlib.h>

#include <algorithm>
#include <memory>

namespace meshflow::io::nektar {

namespace {
constexpr int kLevel = 1;  // fastest zlib level, fixed: same bytes everywhere (the demo mesh.xml: level 6, zlib's default, 4.5 s user, 49.3 MB; level 1 2.3 s, 49.6 MB)
constexpr std::size_t kChunk3 = 3u << 20;        // binary bytes per EVP_EncodeBlock call (a multiple of 3)
constexpr std::size_t kChunk4 = 4u << 20;        // base64 characters per EVP_DecodeBlock call (a multiple of 4)

bool is_b64(unsigned char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '+' || c == '/'; }
}  // namespace

std::string encode(const void* data, std::size_t bytes) {
  // zlib's worst case (compressBound: the input's size and a little) as an uninitialised buffer:
  // only the pages compress2 writes become resident, about the compressed size, where a
  // zero-filled std::string made the whole bound resident (Rotor 67's order-4 mesh: a 0.9 GB
  // array of curve point indices cost 0.9 GB more while it was compressed)
  uLongf zlen = compressBound(static_cast<uLong>(bytes));
  std::unique_ptr<Bytef[]> z(new Bytef[zlen + 2]);
  const int rc = compress2(z.get(), &zlen, static_cast<const Bytef*>(data), static_cast<uLong>(bytes), kLevel);
  if (rc != Z_OK) throw MeshIOError(std::string("zlib compression failed: ") + zError(rc));
  const std::size_t padded = (std::size_t(zlen) + 2) / 3 * 3;  // Nektar++'s zero padding: base64 without '='
  std::fill(z.get() + zlen, z.get() + padded, Bytef(0));
  std::string out(padded / 3 * 4, '\0');
  for (std::size_t i = 0; i < padded; i += kChunk3) {
    const std::size_t n = std::min(kChunk3, padded - i);
    EVP_EncodeBlock(reinterpret_cast<unsigned char*>(out.data()) + i / 3 * 4, z.get() + i, static_cast<int>(n));
  }
  return out;
}

namespace {
// base64 text (whitespace anywhere, '=' padding or none) to bytes
std::string base64_bytes(std::string_view text, const std::string& where) {
  std::string b;
  b.reserve(text.size());
  std::size_t pad = 0;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    if (c == ' ' || c == '\n' || c == '\r' || c == '\t') continue;
    if (c == '=') {
      ++pad;
      continue;
    }
    if (!is_b64(c) || pad)
      throw MeshIOError(where + ": compressed data is not base64 (character '" + std::string(1, static_cast<char>(c)) +
                        "' at position " + std::to_string(i) + " of the section's text): a corrupt or hand-edited file");
    b.push_back(static_cast<char>(c));
  }
  if (b.size() % 4 == 1) throw MeshIOError(where + ": compressed data is not base64 (its length leaves a single character): a truncated section?");
  const std::size_t tail = (4 - b.size() % 4) % 4;  // what the missing '=' would have been
  b.append(tail, '=');
  std::string out(b.size() / 4 * 3, '\0');
  for (std::size_t i = 0; i < b.size(); i += kChunk4) {
    const std::size_t n = std::min(kChunk4, b.size() - i);
    if (EVP_DecodeBlock(reinterpret_cast<unsigned char*>(out.data()) + i / 4 * 3, reinterpret_cast<const unsigned char*>(b.data()) + i,
                        static_cast<int>(n)) < 0)
      throw MeshIOError(where + ": compressed data is not base64");
  }
  out.resize(out.size() - tail);
  return out;
}
}  // namespace

std::string decode(std::string_view text, const std::string& where) {
  const std::string z = base64_bytes(text, where);
  z_stream s{};
  if (inflateInit(&s) != Z_OK) throw MeshIOError(where + ": zlib initialisation failed");
  s.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(z.data()));
  s.avail_in = static_cast<uInt>(z.size());
  std::string out(std::max<std::size_t>(4 * z.size(), 1024), '\0');
  std::size_t have = 0;
  int rc = Z_OK;
  while (rc == Z_OK) {
    if (have == out.size()) out.resize(2 * out.size());
    s.next_out = reinterpret_cast<Bytef*>(out.data() + have);
    s.avail_out = static_cast<uInt>(std::min<std::size_t>(out.size() - have, 1u << 30));
    const uInt before = s.avail_out;
    rc = inflate(&s, Z_NO_FLUSH);
    have += before - s.avail_out;
    if (rc == Z_BUF_ERROR && s.avail_in == 0) break;  // input used up before the stream's end
    if (rc == Z_BUF_ERROR) rc = Z_OK;                 // output full: grow and go on
  }
  const std::string msg = s.msg ? s.msg : zError(rc);
  const std::size_t used = z.size() - s.avail_in;
  inflateEnd(&s);
  if (rc != Z_STREAM_END) {
    if (rc == Z_OK || rc == Z_BUF_ERROR)
      throw MeshIOError(where + ": compressed data ends before its zlib stream does (a truncated section?)");
    throw MeshIOError(where + ": compressed data is not a valid zlib stream (" + msg + "): a corrupt file");
  }
  for (std::size_t i = used; i < z.size(); ++i)  // after the stream: only Nektar++'s zero padding
    if (z[i] != '\0') throw MeshIOError(where + ": compressed data goes on after the end of its zlib stream: a corrupt file");
  out.resize(have);
  return out;
}

}  // namespace meshflow::io::nektar
