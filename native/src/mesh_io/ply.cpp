// PLY (ascii, binary little and big endian): the header parser and the body readers of parse_ply
// (a BinaryReader and an AsciiReader behind one read_ply_body), and write_ply, the writer behind
// save_mesh (double x, y, z and an int32 index list).
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include "text.h"
#include "writers.h"

#include <algorithm>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace larap {
using namespace io_detail;

namespace {

[[noreturn]] void fail_byte(const std::string& name, size_t offset, const std::string& what) {
  throw ParseError(name + ":byte " + std::to_string(offset) + ": " + what);
}

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

// ------------------------------------------------------------------ writing

namespace {

void put_le(std::string& out, const void* value, size_t n) {
  unsigned char b[8];
  std::memcpy(b, value, n);
  if (!host_is_little_endian()) std::reverse(b, b + n);
  out.append(reinterpret_cast<const char*>(b), n);
}

}  // namespace

namespace io_detail {

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

}  // namespace io_detail
}  // namespace larap
