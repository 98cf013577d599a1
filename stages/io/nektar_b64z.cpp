// Nektar++'s B64Z codec: zlib for the compression (the library Nektar++ itself uses, so the
// streams are the same) and OpenSSL's EVP_EncodeBlock / EVP_DecodeBlock for base64 (OpenSSL is
// already linked for the engine's hashes, and neither zlib nor expat has base64; a coder of our
// own would be one more thing to get wrong at a chunk boundary).
#include "stages/io/nektar_b64z.hpp"

#include <openssl/evp.h>
#include <zlib.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <memory>
#include <vector>

namespace meshflow::io::nektar {

namespace {
constexpr int kLevel = 1;  // fastest zlib level, fixed: same bytes everywhere (the demo mesh.xml: level 6, zlib's default, 4.5 s user, 49.3 MB; level 1 2.3 s, 49.6 MB)
constexpr std::size_t kChunk3 = 3u << 20;        // binary bytes per EVP_EncodeBlock call (a multiple of 3)
constexpr std::size_t kChunk4 = 4u << 20;        // base64 characters per EVP_DecodeBlock call (a multiple of 4)

bool is_b64(unsigned char c) { return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '+' || c == '/'; }

// zlib's fixed two-byte header of a level-1 stream (what compress2 writes at kLevel): CMF 0x78
// (deflate, 32 KiB window), FLG 0x01 (FLEVEL 0 "fastest", no dictionary, check bits).
constexpr unsigned char kHeader[2] = {0x78, 0x01};
constexpr std::size_t kPiece = 1u << 20;   // input bytes per independently compressed piece
constexpr std::size_t kWindow = 32u << 10;  // deflate's window: the preset dictionary of a piece
constexpr std::size_t kBatch = 16;          // pieces compressed at once (bounds the memory held)

// One piece of a parallel stream: raw deflate (no header) of in[0, n), primed with the 32 KiB
// before it, ended by a sync flush (byte aligned, not final) or, for the last piece, the final
// block.
std::vector<Bytef> deflate_piece(const Bytef* in, std::size_t n, const Bytef* dict, std::size_t dict_n, bool last) {
  z_stream s{};
  if (deflateInit2(&s, kLevel, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK) throw MeshIOError("zlib initialisation failed");
  if (dict_n > 0 && deflateSetDictionary(&s, dict, static_cast<uInt>(dict_n)) != Z_OK) {
    deflateEnd(&s);
    throw MeshIOError("zlib dictionary failed");
  }
  std::vector<Bytef> out(deflateBound(&s, static_cast<uLong>(n)) + 16);
  s.next_in = const_cast<Bytef*>(in);
  s.avail_in = static_cast<uInt>(n);
  s.next_out = out.data();
  s.avail_out = static_cast<uInt>(out.size());
  const int rc = deflate(&s, last ? Z_FINISH : Z_SYNC_FLUSH);
  const bool complete = last ? rc == Z_STREAM_END : (rc == Z_OK && s.avail_in == 0 && s.avail_out > 0);
  out.resize(out.size() - s.avail_out);
  deflateEnd(&s);
  if (!complete) throw MeshIOError("zlib compression failed");
  return out;
}

// Appends bytes to the base64 text, carrying the 0-2 bytes that do not fill a group of 3.
struct Base64Sink {
  std::string& out;
  unsigned char carry[3];
  std::size_t nc = 0;
  void put(const Bytef* p, std::size_t n) {
    while (nc > 0 && nc < 3 && n > 0) carry[nc++] = *p++, --n;
    if (nc == 3) emit(carry, 3), nc = 0;
    const std::size_t whole = n / 3 * 3;
    for (std::size_t i = 0; i < whole; i += kChunk3) emit(p + i, std::min(kChunk3, whole - i));
    for (std::size_t i = whole; i < n; ++i) carry[nc++] = p[i];
  }
  void emit(const unsigned char* p, std::size_t n) {
    const std::size_t at = out.size();
    out.resize(at + n / 3 * 4);
    EVP_EncodeBlock(reinterpret_cast<unsigned char*>(out.data()) + at, p, static_cast<int>(n));
  }
  void finish() {  // Nektar++'s zero padding to a multiple of 3: base64 without '='
    if (nc == 0) return;
    while (nc < 3) carry[nc++] = 0;
    emit(carry, 3), nc = 0;
  }
};
}  // namespace

std::string encode(const void* data, std::size_t bytes) {
  const auto* in = static_cast<const Bytef*>(data);
  if (bytes <= kPiece) {
    // zlib's worst case (compressBound) as an uninitialised buffer: only the pages compress2
    // writes become resident, about the compressed size
    uLongf zlen = compressBound(static_cast<uLong>(bytes));
    std::unique_ptr<Bytef[]> z(new Bytef[zlen]);
    const int rc = compress2(z.get(), &zlen, in, static_cast<uLong>(bytes), kLevel);
    if (rc != Z_OK) throw MeshIOError(std::string("zlib compression failed: ") + zError(rc));
    std::string out;
    out.reserve((std::size_t(zlen) + 2) / 3 * 4);
    Base64Sink sink{out, {}};
    sink.put(z.get(), zlen);
    sink.finish();
    return out;
  }
  // A large section (the curved points and their index: 1.5 GB on Rotor 67) as one zlib stream
  // made of pieces compressed in parallel, pigz's method (zlib has no parallel deflate): each
  // piece of kPiece input bytes is raw deflate with the 32 KiB before it as its dictionary, so
  // it compresses as well as one stream would, ends byte-aligned (sync flush), and the pieces'
  // concatenation between zlib's header and the Adler-32 of the whole input is one valid
  // stream that any inflate (Nektar++'s, Python's) reads. The pieces are fixed by the input,
  // not by the threads: the same bytes at any thread count.
  const std::size_t n = (bytes + kPiece - 1) / kPiece;
  std::string out;
  out.reserve((compressBound(static_cast<uLong>(bytes)) + 16 * n + 8) / 3 * 4 + 4);  // untouched pages are not resident
  Base64Sink sink{out, {}};
  sink.put(kHeader, 2);
  std::vector<std::vector<Bytef>> piece(kBatch);
  std::vector<uLong> adler(n);
  for (std::size_t b0 = 0; b0 < n; b0 += kBatch) {
    const std::size_t b1 = std::min(n, b0 + kBatch);
    tbb::parallel_for(b0, b1, [&](std::size_t i) {
      const std::size_t at = i * kPiece, len = std::min(kPiece, bytes - at), dict = std::min(at, kWindow);
      piece[i - b0] = deflate_piece(in + at, len, in + at - dict, dict, i + 1 == n);
      adler[i] = adler32_z(1, in + at, len);
    });
    for (std::size_t i = b0; i < b1; ++i) {
      sink.put(piece[i - b0].data(), piece[i - b0].size());
      std::vector<Bytef>().swap(piece[i - b0]);
    }
  }
  uLong a = adler[0];
  for (std::size_t i = 1; i < n; ++i) a = adler32_combine(a, adler[i], static_cast<z_off_t>(std::min(kPiece, bytes - i * kPiece)));
  const unsigned char trailer[4] = {static_cast<unsigned char>(a >> 24), static_cast<unsigned char>(a >> 16),
                                    static_cast<unsigned char>(a >> 8), static_cast<unsigned char>(a)};
  sink.put(trailer, 4);
  sink.finish();
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
