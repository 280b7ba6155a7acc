// OFF (and its COFF, NOFF, STOFF... variants, ascii only): the reader parse_off and write_off,
// the writer behind save_mesh.
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include "text.h"
#include "writers.h"

#include <cstdint>
#include <string>
#include <vector>

namespace larap {
using namespace io_detail;

PolygonMesh parse_off(std::string_view data, const std::string& name) {
  data = skip_bom(data);
  LineReader lines(data, false);
  std::string_view text, tok;
  int64_t line = 0;

  // Next line with a token on it (comments and blank lines skipped).
  auto next_content = [&](Tokens& tk) {
    while (lines.next(text, line)) {
      tk = Tokens{strip_comment(text)};
      Tokens probe = tk;
      if (probe.next(tok)) return true;
    }
    return false;
  };

  Tokens tk;
  if (!next_content(tk)) fail_line(name, 1, "empty file");
  tk.next(tok);
  // Magic: [ST][C][N]OFF. 4OFF / nOFF (other dimensions) and binary OFF are not supported.
  const bool has_magic = tok.size() >= 3 && tok.substr(tok.size() - 3) == "OFF";
  if (!has_magic) fail_line(name, line, "not an OFF file (no OFF magic)");
  for (const char c : tok.substr(0, tok.size() - 3))
    if (c != 'S' && c != 'T' && c != 'C' && c != 'N')
      fail_line(name, line, "unsupported OFF variant " + quote(tok));

  // Counts: on the magic line or the next content line.
  int64_t counts[3] = {0, 0, 0};
  int found = 0;
  Tokens count_tokens = tk;
  if (!Tokens(count_tokens).next(tok)) {
    if (!next_content(count_tokens)) fail_line(name, line, "missing vertex/face counts");
  }
  while (count_tokens.next(tok)) {
    if (tok == "BINARY") fail_line(name, line, "binary OFF is not supported");
    if (found == 3) fail_line(name, line, "too many values on the counts line");
    if (!to_int(tok, counts[found])) fail_line(name, line, "bad count " + quote(tok));
    if (counts[found] < 0) fail_line(name, line, "negative count " + quote(tok));
    ++found;
  }
  if (found < 2) fail_line(name, line, "counts line needs vertex and face counts");
  const int64_t nv = counts[0], nf = counts[1];

  // A vertex line takes at least 6 bytes ("0 0 0\n"), a face line 4 ("1 0\n").
  const uint64_t rem = data.size() - lines.pos() + 1;
  if (static_cast<uint64_t>(nv) > rem / 6 || static_cast<uint64_t>(nf) > rem / 4 ||
      static_cast<uint64_t>(nv) * 6 + static_cast<uint64_t>(nf) * 4 > rem + 4)
    fail_line(name, line, "counts (" + std::to_string(nv) + " vertices, " + std::to_string(nf) +
                              " faces) exceed what the file's " + std::to_string(rem) + " remaining bytes can hold");

  std::vector<double> xyz(static_cast<size_t>(nv) * 3);
  std::vector<int64_t> offsets{0}, indices;
  offsets.reserve(static_cast<size_t>(nf) + 1);
  for (int64_t i = 0; i < nv; ++i) {
    if (!next_content(tk))
      fail_line(name, line, "file ends after " + std::to_string(i) + " of " + std::to_string(nv) + " vertices");
    for (int c = 0; c < 3; ++c) {
      if (!tk.next(tok)) fail_line(name, line, "vertex needs 3 coordinates");
      if (!to_double(tok, xyz[static_cast<size_t>(i) * 3 + c]))
        fail_line(name, line, "vertex coordinate " + quote(tok) + " is not a number");
    }
    // Trailing normals / colours / texture coordinates are ignored.
  }
  for (int64_t f = 0; f < nf; ++f) {
    if (!next_content(tk))
      fail_line(name, line, "file ends after " + std::to_string(f) + " of " + std::to_string(nf) + " faces");
    int64_t n;
    tk.next(tok);
    if (!to_int(tok, n)) fail_line(name, line, "bad face size " + quote(tok));
    if (n <= 0) fail_line(name, line, "face size " + std::to_string(n) + " (must be at least 1)");
    for (int64_t j = 0; j < n; ++j) {
      int64_t v;
      if (!tk.next(tok))
        fail_line(name, line, "face of size " + std::to_string(n) + " lists only " + std::to_string(j) + " vertices");
      if (!to_int(tok, v)) fail_line(name, line, "bad face vertex " + quote(tok));
      if (v < 0 || v >= nv)
        fail_line(name, line, "face vertex " + std::to_string(v) + " is out of range for " + std::to_string(nv) +
                                  " vertices");
      indices.push_back(v);
    }
    // Trailing colour values are ignored.
    offsets.push_back(static_cast<int64_t>(indices.size()));
  }
  return finish(xyz, offsets, indices, name);
}

// ------------------------------------------------------------------ writing

namespace io_detail {

std::string write_off(const PolygonMesh& mesh) {
  std::string out = "OFF\n";
  put_int(out, mesh.num_vertices());
  out += ' ';
  put_int(out, mesh.num_faces());
  out += " 0\n";
  put_ascii_body(out, mesh);
  return out;
}

}  // namespace io_detail
}  // namespace larap
