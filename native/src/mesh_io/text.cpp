// The shared text layer of the mesh readers and writers (declared and described in text.h):
// error messages, number parsing, the line walker, validation of a parsed mesh, ASCII output.
#include "text.h"

#include <larap/errors.h>

#include <charconv>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <utility>

namespace larap::io_detail {
namespace {

// from_chars refuses a leading '+', which some writers emit; accept exactly one.
bool strip_plus(std::string_view& t) {
  if (!t.empty() && t[0] == '+') {
    t.remove_prefix(1);
    if (t.empty() || t[0] == '+' || t[0] == '-') return false;
  }
  return true;
}

}  // namespace

// ------------------------------------------------------------------ reading

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

bool LineReader::next(std::string_view& text, int64_t& line) {
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

std::string_view LineReader::take() {
  const char* b = data_.data() + pos_;
  const void* nl = std::memchr(b, '\n', data_.size() - pos_);
  const size_t end = nl ? static_cast<size_t>(static_cast<const char*>(nl) - data_.data()) : data_.size();
  std::string_view s = data_.substr(pos_, end - pos_);
  if (!s.empty() && s.back() == '\r') s.remove_suffix(1);
  pos_ = nl ? end + 1 : end;
  ++line_;
  return s;
}

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

// ------------------------------------------------------------------ writing

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

}  // namespace larap::io_detail
