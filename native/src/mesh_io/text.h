// The text layer the mesh readers and writers share (native/src/mesh_io/, behind
// include/larap/mesh_io.h): whitespace tokens, whole-token number parsing, the line walker,
// "<name>:<line>: <what>" errors, the hand-over of parsed arrays to validate_mesh, and the ASCII
// writing of numbers, vertices and faces. Internal: larap::io_detail is no public API.
//
// Every reader works on the whole file held in memory and treats it as hostile: each count is
// checked against the bytes that remain before anything is allocated for it, every number must
// parse completely, every index must land in range, and all failures are larap::ParseError with
// "<name>:<line>: <what>" (binary PLY: "<name>:byte <offset>: <what>"). The mesh_io files depend
// on mesh.cpp only, so the fuzz targets can link them alone (LARAP_MESH_IO_SOURCES in CMakeLists.txt).
#pragma once
#include <larap/mesh.h>

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace larap::io_detail {

// ------------------------------------------------------------------ reading

// Printable, bounded rendering of a token for error messages.
std::string quote(std::string_view tok);

// Throws ParseError "<name>:<line>: <what>".
[[noreturn]] void fail_line(const std::string& name, int64_t line, const std::string& what);

inline bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

// Whitespace-separated tokens of one line, one at a time.
struct Tokens {
  std::string_view s;
  size_t i = 0;

  bool next(std::string_view& tok) {
    while (i < s.size() && is_space(s[i])) ++i;
    if (i >= s.size()) return false;
    const size_t b = i;
    while (i < s.size() && !is_space(s[i])) ++i;
    tok = s.substr(b, i - b);
    return true;
  }
  // The text after the last token returned (leading whitespace kept).
  std::string_view rest() const { return s.substr(i); }
};

// The whole token must be a number. Overflow parses to +-inf (rejected later by validate_mesh),
// underflow to a denormal or zero, as strtod does.
bool to_double(std::string_view t, double& out);
// The whole token must be an integer (one leading '+' accepted).
bool to_int(std::string_view t, int64_t& out);

// The part of `s` before its first '#'.
std::string_view strip_comment(std::string_view s);
// `data` without a leading UTF-8 byte order mark.
std::string_view skip_bom(std::string_view data);

// Walks text line by line (`\n` or `\r\n` endings). With `continuation`, a line ending in a
// backslash is joined with the next one (OBJ). Also reports each logical line's raw byte span.
class LineReader {
 public:
  LineReader(std::string_view data, bool continuation) : data_(data), cont_(continuation) {}

  // Next logical line; `line` is the 1-based number of its first physical line.
  bool next(std::string_view& text, int64_t& line);

  size_t pos() const { return pos_; }
  // Bytes of the last logical line, its line ending(s) included.
  std::string_view raw() const { return data_.substr(raw_begin_, pos_ - raw_begin_); }

 private:
  static bool ends_with_backslash(std::string_view s) { return !s.empty() && s.back() == '\\'; }

  std::string_view take();

  std::string_view data_;
  bool cont_;
  size_t pos_ = 0, raw_begin_ = 0;
  int64_t line_ = 0;
  std::string joined_;
};

// validate_mesh reports problems as InvalidInput; inside a file they are parse errors.
PolygonMesh finish(std::vector<double>& xyz, std::vector<int64_t>& offsets,
                   std::vector<int64_t>& indices, const std::string& name);

// ------------------------------------------------------------------ writing

// Shortest form that reads back exactly.
void put_double(std::string& out, double v);
void put_int(std::string& out, int64_t v);
// "x y z" of vertex i.
void put_vertex(std::string& out, const PolygonMesh& mesh, int64_t i);
// The vertex and face lines that ASCII PLY and OFF share: "x y z" per vertex, then "n i0 i1 ..."
// per face.
void put_ascii_body(std::string& out, const PolygonMesh& mesh);

}  // namespace larap::io_detail
