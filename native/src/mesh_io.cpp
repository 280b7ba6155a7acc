// Mesh file readers and writers: Wavefront OBJ, PLY (ascii, binary little/big endian), OFF.
//
// Every reader works on the whole file held in memory and treats it as hostile: each count is
// checked against the bytes that remain before anything is allocated for it, every number must
// parse completely, every index must land in range, and all failures are larap::ParseError with
// "<name>:<line>: <what>" (binary PLY: "<name>:byte <offset>: <what>"). This file depends on
// mesh.cpp only, so the fuzz targets can link it alone.
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace larap {
namespace {

// ------------------------------------------------------------------ errors and tokens

// Printable, bounded rendering of a token for error messages.
std::string quote(std::string_view tok) {
  std::string out = "'";
  const size_t limit = 40;
  for (size_t i = 0; i < tok.size() && i < limit; ++i) {
    const unsigned char c = static_cast<unsigned char>(tok[i]);
    if (c >= 32 && c < 127) {
      out += static_cast<char>(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02x", c);
      out += buf;
    }
  }
  if (tok.size() > limit) out += "...";
  return out + "'";
}

[[noreturn]] void fail_line(const std::string& name, int64_t line, const std::string& what) {
  throw ParseError(name + ":" + std::to_string(line) + ": " + what);
}

[[noreturn]] void fail_byte(const std::string& name, size_t offset, const std::string& what) {
  throw ParseError(name + ":byte " + std::to_string(offset) + ": " + what);
}

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

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

// from_chars refuses a leading '+', which some writers emit; accept exactly one.
bool strip_plus(std::string_view& t) {
  if (!t.empty() && t[0] == '+') {
    t.remove_prefix(1);
    if (t.empty() || t[0] == '+' || t[0] == '-') return false;
  }
  return true;
}

// The whole token must be a number. Overflow parses to +-inf (rejected later by validate_mesh),
// underflow to a denormal or zero, as strtod does.
bool to_double(std::string_view t, double& out) {
  if (t.empty() || !strip_plus(t)) return false;
  const char* end = t.data() + t.size();
  const auto r = std::from_chars(t.data(), end, out);
  if (r.ptr != end) return false;
  if (r.ec == std::errc()) return true;
  if (r.ec != std::errc::result_out_of_range || t.size() > 400) return false;
  char buf[402];
  std::memcpy(buf, t.data(), t.size());
  buf[t.size()] = '\0';
  out = std::strtod(buf, nullptr);
  return true;
}

bool to_int(std::string_view t, int64_t& out) {
  if (t.empty() || !strip_plus(t)) return false;
  const char* end = t.data() + t.size();
  const auto r = std::from_chars(t.data(), end, out);
  return r.ec == std::errc() && r.ptr == end;
}

std::string_view strip_comment(std::string_view s) {
  const size_t hash = s.find('#');
  return hash == std::string_view::npos ? s : s.substr(0, hash);
}

std::string_view skip_bom(std::string_view data) {
  if (data.size() >= 3 && data.substr(0, 3) == "\xEF\xBB\xBF") data.remove_prefix(3);
  return data;
}

// Walks text line by line (`\n` or `\r\n` endings). With `continuation`, a line ending in a
// backslash is joined with the next one (OBJ). Also reports each logical line's raw byte span.
class LineReader {
 public:
  LineReader(std::string_view data, bool continuation) : data_(data), cont_(continuation) {}

  // Next logical line; `line` is the 1-based number of its first physical line.
  bool next(std::string_view& text, int64_t& line) {
    if (pos_ >= data_.size()) return false;
    raw_begin_ = pos_;
    line = line_ + 1;
    std::string_view phys = take();
    if (!cont_ || !ends_with_backslash(phys)) {
      text = phys;
      return true;
    }
    joined_.assign(phys.data(), phys.size() - 1);
    while (pos_ < data_.size()) {
      phys = take();
      joined_ += ' ';
      if (!ends_with_backslash(phys)) {
        joined_.append(phys.data(), phys.size());
        break;
      }
      joined_.append(phys.data(), phys.size() - 1);
    }
    text = joined_;
    return true;
  }

  size_t pos() const { return pos_; }
  // Bytes of the last logical line, its line ending(s) included.
  std::string_view raw() const { return data_.substr(raw_begin_, pos_ - raw_begin_); }

 private:
  static bool ends_with_backslash(std::string_view s) { return !s.empty() && s.back() == '\\'; }

  std::string_view take() {
    const char* b = data_.data() + pos_;
    const void* nl = std::memchr(b, '\n', data_.size() - pos_);
    const size_t end = nl ? static_cast<size_t>(static_cast<const char*>(nl) - data_.data()) : data_.size();
    std::string_view s = data_.substr(pos_, end - pos_);
    if (!s.empty() && s.back() == '\r') s.remove_suffix(1);
    pos_ = nl ? end + 1 : end;
    ++line_;
    return s;
  }

  std::string_view data_;
  bool cont_;
  size_t pos_ = 0, raw_begin_ = 0;
  int64_t line_ = 0;
  std::string joined_;
};

// validate_mesh reports problems as InvalidInput; inside a file they are parse errors.
PolygonMesh finish(std::vector<double>& xyz, std::vector<int64_t>& offsets,
                   std::vector<int64_t>& indices, const std::string& name) {
  PolygonMesh mesh;
  const Eigen::Index n = static_cast<Eigen::Index>(xyz.size() / 3);
  mesh.vertices = Eigen::Map<const RowMatrixX3d>(xyz.data(), n, 3);
  mesh.face_offsets = std::move(offsets);
  mesh.face_indices = std::move(indices);
  try {
    validate_mesh(mesh);
  } catch (const ParseError&) {
    throw;
  } catch (const InvalidInput& e) {
    throw ParseError(name + ": " + e.what());
  }
  return mesh;
}

// ------------------------------------------------------------------ OBJ

// One `f` entry: "v", "v/vt", "v//vn" or "v/vt/vn". Returns the raw (1-based or negative) index.
bool parse_obj_ref(std::string_view tok, int64_t& v) {
  const size_t s1 = tok.find('/');
  if (!to_int(tok.substr(0, s1), v)) return false;
  if (s1 == std::string_view::npos) return true;
  std::string_view rest = tok.substr(s1 + 1);
  const size_t s2 = rest.find('/');
  const std::string_view vt = rest.substr(0, s2);
  const std::string_view vn = s2 == std::string_view::npos ? std::string_view() : rest.substr(s2 + 1);
  int64_t unused;
  if (!vt.empty() && !to_int(vt, unused)) return false;
  if (!vn.empty() && !to_int(vn, unused)) return false;  // also rejects a third '/'
  return true;
}

}  // namespace

PolygonMesh parse_obj(std::string_view data, const std::string& name) {
  data = skip_bom(data);
  std::vector<double> xyz;
  std::vector<int64_t> offsets{0}, indices;
  // Positive indices past the vertices read so far (legal if the vertex comes later): checked at the end.
  std::vector<std::pair<int64_t, int64_t>> forward;  // (line, 0-based index)

  LineReader lines(data, true);
  std::string_view text, tok;
  int64_t line = 0;
  while (lines.next(text, line)) {
    Tokens tk{strip_comment(text)};
    if (!tk.next(tok)) continue;
    if (tok == "v") {
      for (int c = 0; c < 3; ++c) {
        double x;
        if (!tk.next(tok)) fail_line(name, line, "vertex needs 3 coordinates");
        if (!to_double(tok, x)) fail_line(name, line, "vertex coordinate " + quote(tok) + " is not a number");
        xyz.push_back(x);
      }
      // Anything after xyz (w or vertex colours) carries nothing we use.
    } else if (tok == "f") {
      const int64_t nv = static_cast<int64_t>(xyz.size() / 3);
      size_t count = 0;
      while (tk.next(tok)) {
        int64_t i;
        if (!parse_obj_ref(tok, i)) fail_line(name, line, "bad face vertex " + quote(tok));
        if (i == 0) fail_line(name, line, "face vertex index 0 (OBJ indices start at 1)");
        if (i < 0) {
          i += nv;  // relative to the vertices read so far; cannot overflow as nv >= 0
          if (i < 0) fail_line(name, line, "relative index " + quote(tok) + " points before the first vertex");
        } else {
          i -= 1;
          if (i >= nv) forward.emplace_back(line, i);
        }
        indices.push_back(i);
        ++count;
      }
      if (count == 0) fail_line(name, line, "face without vertices");
      offsets.push_back(static_cast<int64_t>(indices.size()));
    }
    // vt, vn, vp, g, o, s, usemtl, mtllib, l, p and unknown keywords carry no geometry we use.
  }
  const int64_t nv = static_cast<int64_t>(xyz.size() / 3);
  for (const auto& [at, i] : forward)
    if (i >= nv)
      fail_line(name, at, "face vertex index " + std::to_string(i + 1) + " is out of range (the file has " +
                              std::to_string(nv) + " vertices)");
  return finish(xyz, offsets, indices, name);
}

// ------------------------------------------------------------------ PLY

namespace {

enum class Scalar : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

size_t scalar_size(Scalar t) {
  switch (t) {
    case Scalar::I8: case Scalar::U8: return 1;
    case Scalar::I16: case Scalar::U16: return 2;
    case Scalar::I32: case Scalar::U32: case Scalar::F32: return 4;
    case Scalar::F64: return 8;
  }
  return 8;
}

bool is_integer(Scalar t) { return t != Scalar::F32 && t != Scalar::F64; }

bool scalar_from_name(std::string_view s, Scalar& t) {
  static const std::pair<const char*, Scalar> names[] = {
      {"char", Scalar::I8},     {"int8", Scalar::I8},     {"uchar", Scalar::U8},     {"uint8", Scalar::U8},
      {"short", Scalar::I16},   {"int16", Scalar::I16},   {"ushort", Scalar::U16},   {"uint16", Scalar::U16},
      {"int", Scalar::I32},     {"int32", Scalar::I32},   {"uint", Scalar::U32},     {"uint32", Scalar::U32},
      {"float", Scalar::F32},   {"float32", Scalar::F32}, {"double", Scalar::F64},   {"float64", Scalar::F64}};
  for (const auto& [n, v] : names)
    if (s == n) return t = v, true;
  return false;
}

struct PlyProperty {
  std::string name;
  Scalar type = Scalar::F32;   // the value type (list items for a list)
  bool list = false;
  Scalar count_type = Scalar::U8;
};

struct PlyElement {
  std::string name;
  uint64_t count = 0;
  std::vector<PlyProperty> props;
  int64_t line = 0;  // header line, for messages
};

bool host_is_little_endian() {
  const uint16_t one = 1;
  unsigned char b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

// Binary body: scalars are read with memcpy (no alignment assumptions) and byte-swapped as needed.
class BinaryReader {
 public:
  BinaryReader(std::string_view body, size_t base, bool big_endian, const std::string& name)
      : p_(reinterpret_cast<const unsigned char*>(body.data())), n_(body.size()), base_(base),
        swap_(big_endian == host_is_little_endian()), name_(name) {}

  static constexpr bool binary = true;
  size_t remaining() const { return n_ - pos_; }
  [[noreturn]] void fail(const std::string& what) const { fail_byte(name_, base_ + pos_, what); }

  double read_double(Scalar t) { return decode<double>(t); }
  int64_t read_int(Scalar t) { return decode<int64_t>(t); }  // t is an integer type
  void skip_values(Scalar t, uint64_t count) {
    if (count > remaining() / scalar_size(t)) fail("unexpected end of data");
    pos_ += static_cast<size_t>(count) * scalar_size(t);
  }

 private:
  template <class Out>
  Out decode(Scalar t) {
    const size_t k = scalar_size(t);
    if (remaining() < k) fail("unexpected end of data");
    unsigned char b[8];
    std::memcpy(b, p_ + pos_, k);
    if (swap_) std::reverse(b, b + k);
    pos_ += k;
    switch (t) {
      case Scalar::I8: { int8_t v; std::memcpy(&v, b, 1); return static_cast<Out>(v); }
      case Scalar::U8: { uint8_t v; std::memcpy(&v, b, 1); return static_cast<Out>(v); }
      case Scalar::I16: { int16_t v; std::memcpy(&v, b, 2); return static_cast<Out>(v); }
      case Scalar::U16: { uint16_t v; std::memcpy(&v, b, 2); return static_cast<Out>(v); }
      case Scalar::I32: { int32_t v; std::memcpy(&v, b, 4); return static_cast<Out>(v); }
      case Scalar::U32: { uint32_t v; std::memcpy(&v, b, 4); return static_cast<Out>(v); }
      case Scalar::F32: { float v; std::memcpy(&v, b, 4); return as<Out>(v); }
      case Scalar::F64: { double v; std::memcpy(&v, b, 8); return as<Out>(v); }
    }
    return Out();
  }
  // Floats only ever reach a double (the header refuses float counts and indices).
  template <class Out, class F>
  static Out as(F v) {
    if constexpr (std::is_floating_point_v<Out>) return static_cast<Out>(v);
    else return Out();
  }

  const unsigned char* p_;
  size_t n_, pos_ = 0, base_;
  bool swap_;
  const std::string& name_;
};

// Ascii body: a stream of whitespace-separated tokens; line structure is not required.
class AsciiReader {
 public:
  AsciiReader(std::string_view body, int64_t first_line, const std::string& name)
      : s_(body), line_(first_line), name_(name) {}

  static constexpr bool binary = false;
  size_t remaining() const { return s_.size() - pos_; }
  [[noreturn]] void fail(const std::string& what) const { fail_line(name_, line_, what); }

  double read_double(Scalar) {
    const std::string_view t = token();
    double v;
    if (!to_double(t, v)) fail("expected a number, got " + quote(t));
    return v;
  }
  int64_t read_int(Scalar) {
    const std::string_view t = token();
    int64_t v;
    if (!to_int(t, v)) fail("expected an integer, got " + quote(t));
    return v;
  }
  void skip_values(Scalar t, uint64_t count) {
    for (uint64_t i = 0; i < count; ++i) is_integer(t) ? (void)read_int(t) : (void)read_double(t);
  }

 private:
  std::string_view token() {
    while (pos_ < s_.size() && (is_space(s_[pos_]) || s_[pos_] == '\n')) {
      if (s_[pos_] == '\n') ++line_;
      ++pos_;
    }
    if (pos_ >= s_.size()) fail("unexpected end of file");
    const size_t b = pos_;
    while (pos_ < s_.size() && !is_space(s_[pos_]) && s_[pos_] != '\n') ++pos_;
    return s_.substr(b, pos_ - b);
  }

  std::string_view s_;
  size_t pos_ = 0;
  int64_t line_;
  const std::string& name_;
};

struct PlyTargets {
  const PlyElement* vertex = nullptr;
  const PlyElement* face = nullptr;
  int xyz[3] = {-1, -1, -1};  // property positions of x, y, z in the vertex element
  int indices = -1;           // property position of the index list in the face element
};

template <class Reader>
void read_ply_body(Reader& in, const std::vector<PlyElement>& elements, const PlyTargets& tg,
                   std::vector<double>& xyz, std::vector<int64_t>& offsets, std::vector<int64_t>& indices) {
  const int64_t nv = static_cast<int64_t>(tg.vertex->count);  // fits: checked in the header
  for (const PlyElement& el : elements) {
    if (el.props.empty() || el.count == 0) continue;  // nothing stored for it
    // Least bytes one item occupies: binary, its scalars and list counts; ascii, one digit and
    // one separator per property.
    size_t min_size = 0;
    bool fixed = true;
    for (const PlyProperty& p : el.props) {
      if (Reader::binary) min_size += scalar_size(p.list ? p.count_type : p.type);
      else min_size += 2;
      fixed = fixed && !p.list;
    }
    // Ascii allows one byte of slack: the last value needs no separator after it.
    const size_t slack = Reader::binary ? 0 : 1;
    if (el.count > (in.remaining() + slack) / min_size)
      in.fail("element '" + el.name + "' declares " + std::to_string(el.count) + " items but only " +
              std::to_string(in.remaining()) + " bytes remain");

    const bool is_vertex = &el == tg.vertex, is_face = &el == tg.face;
    if (!is_vertex && !is_face && Reader::binary && fixed) {  // skip the block at once
      in.skip_values(Scalar::U8, el.count * min_size);
      continue;
    }
    if (is_vertex) xyz.resize(static_cast<size_t>(el.count) * 3);
    if (is_face) offsets.reserve(static_cast<size_t>(el.count) + 1);

    for (uint64_t item = 0; item < el.count; ++item) {
      for (size_t k = 0; k < el.props.size(); ++k) {
        const PlyProperty& p = el.props[k];
        if (!p.list) {
          if (is_vertex) {
            const double v = in.read_double(p.type);
            for (int c = 0; c < 3; ++c)
              if (tg.xyz[c] == static_cast<int>(k)) xyz[static_cast<size_t>(item) * 3 + c] = v;
          } else {
            in.skip_values(p.type, 1);
          }
          continue;
        }
        const int64_t n = in.read_int(p.count_type);
        if (n < 0) in.fail("negative list length " + std::to_string(n));
        const size_t item_min = Reader::binary ? scalar_size(p.type) : 2;
        if (static_cast<uint64_t>(n) > (in.remaining() + slack) / item_min)
          in.fail("list of " + std::to_string(n) + " values but only " + std::to_string(in.remaining()) +
                  " bytes remain");
        if (!(is_face && tg.indices == static_cast<int>(k))) {
          in.skip_values(p.type, static_cast<uint64_t>(n));
          continue;
        }
        if (n == 0) in.fail("face " + std::to_string(item) + " has no vertices");
        for (int64_t j = 0; j < n; ++j) {
          const int64_t v = in.read_int(p.type);
          if (v < 0 || v >= nv)
            in.fail("face " + std::to_string(item) + " refers to vertex " + std::to_string(v) + ", out of range for " +
                    std::to_string(nv) + " vertices");
          indices.push_back(v);
        }
        offsets.push_back(static_cast<int64_t>(indices.size()));
      }
    }
  }
}

}  // namespace

PolygonMesh parse_ply(std::string_view data, const std::string& name) {
  LineReader lines(data, false);
  std::string_view text, tok;
  int64_t line = 0;
  if (!lines.next(text, line) || text != "ply") fail_line(name, 1, "not a PLY file (no 'ply' magic line)");

  enum class Encoding { None, Ascii, Little, Big } enc = Encoding::None;
  std::vector<PlyElement> elements;
  bool ended = false;
  while (!ended && lines.next(text, line)) {
    Tokens tk{text};
    if (!tk.next(tok)) continue;
    if (tok == "comment" || tok == "obj_info") continue;
    if (tok == "end_header") {
      ended = true;
    } else if (tok == "format") {
      if (enc != Encoding::None) fail_line(name, line, "second format line");
      if (!tk.next(tok)) fail_line(name, line, "format line without encoding");
      if (tok == "ascii") enc = Encoding::Ascii;
      else if (tok == "binary_little_endian") enc = Encoding::Little;
      else if (tok == "binary_big_endian") enc = Encoding::Big;
      else fail_line(name, line, "unknown PLY encoding " + quote(tok));
    } else if (tok == "element") {
      PlyElement el;
      el.line = line;
      std::string_view count;
      if (!tk.next(tok) || !tk.next(count)) fail_line(name, line, "element line needs a name and a count");
      el.name = std::string(tok);
      if (!count.empty() && count[0] == '-') fail_line(name, line, "negative element count " + quote(count));
      const auto r = std::from_chars(count.data(), count.data() + count.size(), el.count);
      if (r.ec != std::errc() || r.ptr != count.data() + count.size())
        fail_line(name, line, "bad element count " + quote(count));
      for (const PlyElement& other : elements)
        if (other.name == el.name) fail_line(name, line, "element '" + el.name + "' declared twice");
      elements.push_back(std::move(el));
    } else if (tok == "property") {
      if (elements.empty()) fail_line(name, line, "property before any element");
      PlyProperty p;
      if (!tk.next(tok)) fail_line(name, line, "property line without a type");
      if (tok == "list") {
        p.list = true;
        if (!tk.next(tok) || !scalar_from_name(tok, p.count_type))
          fail_line(name, line, "bad list count type " + quote(tok));
        if (!is_integer(p.count_type)) fail_line(name, line, "list count type must be an integer type");
        if (!tk.next(tok)) fail_line(name, line, "list property without an item type");
      }
      if (!scalar_from_name(tok, p.type)) fail_line(name, line, "unknown property type " + quote(tok));
      if (!tk.next(tok)) fail_line(name, line, "property without a name");
      p.name = std::string(tok);
      for (const PlyProperty& other : elements.back().props)
        if (other.name == p.name) fail_line(name, line, "property '" + p.name + "' declared twice");
      elements.back().props.push_back(std::move(p));
    } else {
      fail_line(name, line, "unknown header keyword " + quote(tok));
    }
  }
  if (!ended) fail_line(name, line, "header has no end_header line");
  if (enc == Encoding::None) fail_line(name, line, "header has no format line");

  PlyTargets tg;
  for (const PlyElement& el : elements) {
    if (el.name == "vertex") tg.vertex = &el;
    if (el.name == "face") tg.face = &el;
  }
  if (!tg.vertex) fail_line(name, line, "no vertex element");
  if (tg.vertex->count > static_cast<uint64_t>(std::numeric_limits<int32_t>::max()) * 64)
    fail_line(name, tg.vertex->line, "vertex count " + std::to_string(tg.vertex->count) + " is too large");
  const char* axes[3] = {"x", "y", "z"};
  for (size_t k = 0; k < tg.vertex->props.size(); ++k)
    for (int c = 0; c < 3; ++c)
      if (tg.vertex->props[k].name == axes[c]) {
        if (tg.vertex->props[k].list) fail_line(name, tg.vertex->line, std::string("vertex property ") + axes[c] + " is a list");
        tg.xyz[c] = static_cast<int>(k);
      }
  for (int c = 0; c < 3; ++c)
    if (tg.xyz[c] < 0) fail_line(name, tg.vertex->line, std::string("vertex element has no property ") + axes[c]);
  if (tg.face) {
    for (size_t k = 0; k < tg.face->props.size() && tg.indices < 0; ++k) {
      const PlyProperty& p = tg.face->props[k];
      if (p.name == "vertex_indices" || p.name == "vertex_index") {
        if (!p.list || !is_integer(p.type))
          fail_line(name, tg.face->line, "'" + p.name + "' must be a list of an integer type");
        tg.indices = static_cast<int>(k);
      }
    }
    if (tg.indices < 0) fail_line(name, tg.face->line, "face element has no vertex_indices list");
  }

  std::vector<double> xyz;
  std::vector<int64_t> offsets{0}, indices;
  const size_t body = lines.pos();
  if (enc == Encoding::Ascii) {
    AsciiReader in(data.substr(body), line + 1, name);
    read_ply_body(in, elements, tg, xyz, offsets, indices);
  } else {
    BinaryReader in(data.substr(body), body, enc == Encoding::Big, name);
    read_ply_body(in, elements, tg, xyz, offsets, indices);
  }
  return finish(xyz, offsets, indices, name);
}

// ------------------------------------------------------------------ OFF

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

// ------------------------------------------------------------------ files

namespace {

std::string read_file(const std::string& path) {
  errno = 0;
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) {
    const int e = errno;
    if (e == ENOENT || e == ENOTDIR) throw FileNotFound("no such file: " + path);
    throw IOFailure("cannot open " + path + ": " + std::strerror(e));
  }
  std::string data;
  char buf[1 << 16];
  size_t got;
  while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) data.append(buf, got);
  const bool bad = std::ferror(f) != 0;
  const int e = errno;
  std::fclose(f);
  if (bad) throw IOFailure("cannot read " + path + ": " + std::strerror(e));
  return data;
}

// Writes `bytes` to `path` through `path.tmp` and a rename, so an existing file survives failure.
void write_atomic(const std::string& path, const std::string& bytes) {
  const std::string tmp = path + ".tmp";
  errno = 0;
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) throw IOFailure("cannot write " + tmp + ": " + std::strerror(errno));
  int err = 0;
  if (std::fwrite(bytes.data(), 1, bytes.size(), f) != bytes.size() || std::fflush(f) != 0) err = errno ? errno : EIO;
  if (std::fclose(f) != 0 && !err) err = errno ? errno : EIO;
  if (!err && std::rename(tmp.c_str(), path.c_str()) != 0) err = errno ? errno : EIO;
  if (err) {
    std::remove(tmp.c_str());
    throw IOFailure("cannot write " + path + ": " + std::strerror(err));
  }
}

void put_double(std::string& out, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);  // shortest form that reads back exactly
  out.append(buf, r.ptr);
}

void put_int(std::string& out, int64_t v) {
  char buf[24];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
}

void put_vertex(std::string& out, const PolygonMesh& mesh, int64_t i) {
  for (int c = 0; c < 3; ++c) {
    if (c) out += ' ';
    put_double(out, mesh.vertices(i, c));
  }
}

// The vertex and face lines that ASCII PLY and OFF share: "x y z" per vertex, then "n i0 i1 ..."
// per face.
void put_ascii_body(std::string& out, const PolygonMesh& mesh) {
  for (int64_t i = 0; i < mesh.num_vertices(); ++i) {
    put_vertex(out, mesh, i);
    out += '\n';
  }
  for (int64_t f = 0; f < mesh.num_faces(); ++f) {
    put_int(out, mesh.face_offsets[f + 1] - mesh.face_offsets[f]);
    for (int64_t k = mesh.face_offsets[f]; k < mesh.face_offsets[f + 1]; ++k) {
      out += ' ';
      put_int(out, mesh.face_indices[k]);
    }
    out += '\n';
  }
}

std::string write_obj(const PolygonMesh& mesh) {
  std::string out = "# written by LARAP\n";
  out.reserve(static_cast<size_t>(mesh.num_vertices()) * 60 + mesh.face_indices.size() * 9);
  for (int64_t i = 0; i < mesh.num_vertices(); ++i) {
    out += "v ";
    put_vertex(out, mesh, i);
    out += '\n';
  }
  for (int64_t f = 0; f < mesh.num_faces(); ++f) {
    out += 'f';
    for (int64_t k = mesh.face_offsets[f]; k < mesh.face_offsets[f + 1]; ++k) {
      out += ' ';
      put_int(out, mesh.face_indices[k] + 1);
    }
    out += '\n';
  }
  return out;
}

// The template with each `v` line's xyz replaced; empty when its vertex count differs.
std::string write_obj_from_template(const PolygonMesh& mesh, std::string_view tpl) {
  int64_t count = 0;
  {
    LineReader lines(tpl, true);
    std::string_view text, tok;
    int64_t line;
    while (lines.next(text, line)) {
      Tokens tk{text};
      if (tk.next(tok) && tok == "v") ++count;
    }
  }
  if (count != mesh.num_vertices()) return std::string();

  std::string out;
  out.reserve(tpl.size() + tpl.size() / 4);
  LineReader lines(tpl, true);
  std::string_view text, tok;
  int64_t line, i = 0;
  while (lines.next(text, line)) {
    Tokens tk{text};
    if (!(tk.next(tok) && tok == "v")) {
      out.append(lines.raw().data(), lines.raw().size());
      continue;
    }
    for (int c = 0; c < 3 && tk.next(tok); ++c) {
    }
    out += "v ";
    put_vertex(out, mesh, i++);
    out.append(tk.rest().data(), tk.rest().size());  // colours, comments
    const std::string_view raw = lines.raw();
    out += raw.size() >= 2 && raw.substr(raw.size() - 2) == "\r\n" ? "\r\n" : "\n";
  }
  return out;
}

void put_le(std::string& out, const void* value, size_t n) {
  unsigned char b[8];
  std::memcpy(b, value, n);
  if (!host_is_little_endian()) std::reverse(b, b + n);
  out.append(reinterpret_cast<const char*>(b), n);
}

std::string write_ply(const PolygonMesh& mesh, bool ascii) {
  const int64_t nv = mesh.num_vertices(), nf = mesh.num_faces();
  if (nv > std::numeric_limits<int32_t>::max())
    throw InvalidInput("PLY output stores int32 vertex indices; the mesh has " + std::to_string(nv) + " vertices");
  int64_t largest = 0;
  for (int64_t f = 0; f < nf; ++f) largest = std::max(largest, mesh.face_offsets[f + 1] - mesh.face_offsets[f]);
  const bool wide = largest > 255;  // face sizes past a uchar take an int count
  std::string out = "ply\nformat ";
  out += ascii ? "ascii" : "binary_little_endian";
  out += " 1.0\ncomment written by LARAP\nelement vertex ";
  put_int(out, nv);
  out += "\nproperty double x\nproperty double y\nproperty double z\nelement face ";
  put_int(out, nf);
  out += wide ? "\nproperty list int int vertex_indices\nend_header\n"
              : "\nproperty list uchar int vertex_indices\nend_header\n";
  if (ascii) {
    put_ascii_body(out, mesh);
    return out;
  }
  out.reserve(out.size() + static_cast<size_t>(nv) * 24 + static_cast<size_t>(nf) * 4 + mesh.face_indices.size() * 4);
  for (int64_t i = 0; i < nv; ++i)
    for (int c = 0; c < 3; ++c) {
      const double v = mesh.vertices(i, c);
      put_le(out, &v, 8);
    }
  for (int64_t f = 0; f < nf; ++f) {
    const int64_t n = mesh.face_offsets[f + 1] - mesh.face_offsets[f];
    if (wide) {
      const int32_t n32 = static_cast<int32_t>(n);
      put_le(out, &n32, 4);
    } else {
      const uint8_t n8 = static_cast<uint8_t>(n);
      put_le(out, &n8, 1);
    }
    for (int64_t k = mesh.face_offsets[f]; k < mesh.face_offsets[f + 1]; ++k) {
      const int32_t v = static_cast<int32_t>(mesh.face_indices[k]);
      put_le(out, &v, 4);
    }
  }
  return out;
}

std::string write_off(const PolygonMesh& mesh) {
  std::string out = "OFF\n";
  put_int(out, mesh.num_vertices());
  out += ' ';
  put_int(out, mesh.num_faces());
  out += " 0\n";
  put_ascii_body(out, mesh);
  return out;
}

}  // namespace

MeshFormat format_from_path(const std::string& path) {
  const size_t slash = path.find_last_of("/\\");
  const size_t dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash))
    throw InvalidInput("cannot tell the mesh format of '" + path + "': no extension (expected .obj, .ply or .off)");
  std::string ext = path.substr(dot + 1);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == "obj") return MeshFormat::OBJ;
  if (ext == "ply") return MeshFormat::PLY;
  if (ext == "off") return MeshFormat::OFF;
  throw InvalidInput("unsupported mesh format '." + ext + "' of '" + path + "' (expected .obj, .ply or .off)");
}

PolygonMesh load_mesh(const std::string& path) {
  const MeshFormat fmt = format_from_path(path);
  const std::string data = read_file(path);
  switch (fmt) {
    case MeshFormat::OBJ: return parse_obj(data, path);
    case MeshFormat::PLY: return parse_ply(data, path);
    case MeshFormat::OFF: return parse_off(data, path);
  }
  throw InvalidInput("unsupported mesh format");
}

void save_mesh(const std::string& path, const PolygonMesh& mesh, bool ascii, const std::string& template_obj) {
  const MeshFormat fmt = format_from_path(path);
  validate_mesh(mesh);
  if (mesh.face_offsets.back() != static_cast<int64_t>(mesh.face_indices.size()))
    throw InvalidInput("face offsets end at " + std::to_string(mesh.face_offsets.back()) + " but there are " +
                       std::to_string(mesh.face_indices.size()) + " face indices");
  std::string bytes;
  switch (fmt) {
    case MeshFormat::OBJ:
      if (!template_obj.empty()) bytes = write_obj_from_template(mesh, read_file(template_obj));
      if (bytes.empty()) bytes = write_obj(mesh);
      break;
    case MeshFormat::PLY: bytes = write_ply(mesh, ascii); break;
    case MeshFormat::OFF: bytes = write_off(mesh); break;
  }
  write_atomic(path, bytes);
}

}  // namespace larap
