// Wavefront OBJ: the reader (parse_obj: `v`, `f` and `l` statements, `\` continuations, relative
// and forward indices) and the two writers behind save_mesh: a plain OBJ, and a template OBJ
// copied line by line with only the `v` positions replaced.
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include "text.h"
#include "writers.h"

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace larap {
using namespace io_detail;

namespace {

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
  std::vector<uint8_t> forward_line;                 // per entry of forward: from an `l` statement

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
    } else if (tok == "f" || tok == "l") {
      // A face, or a polyline (`l`): each of its segments is a face of two vertices, a loose
      // edge (mesh.h's segments).
      const bool polyline = tok == "l";
      const char* what = polyline ? "line" : "face";
      const int64_t nv = static_cast<int64_t>(xyz.size() / 3);
      const size_t first = indices.size();
      while (tk.next(tok)) {
        int64_t i;
        if (!parse_obj_ref(tok, i)) fail_line(name, line, std::string("bad ") + what + " vertex " + quote(tok));
        if (i == 0) fail_line(name, line, std::string(what) + " vertex index 0 (OBJ indices start at 1)");
        if (i < 0) {
          i += nv;  // relative to the vertices read so far; cannot overflow as nv >= 0
          if (i < 0) fail_line(name, line, "relative index " + quote(tok) + " points before the first vertex");
        } else {
          i -= 1;
          if (i >= nv) {
            forward.emplace_back(line, i);
            forward_line.push_back(polyline);
          }
        }
        indices.push_back(i);
      }
      const size_t count = indices.size() - first;
      if (count == 0) fail_line(name, line, std::string(what) + " without vertices");
      if (!polyline) {
        offsets.push_back(static_cast<int64_t>(indices.size()));
      } else {
        if (count < 2) fail_line(name, line, "line needs at least 2 vertices");
        const std::vector<int64_t> ids(indices.begin() + int64_t(first), indices.end());
        indices.resize(first);
        for (size_t k = 0; k + 1 < ids.size(); ++k) {
          indices.push_back(ids[k]);
          indices.push_back(ids[k + 1]);
          offsets.push_back(static_cast<int64_t>(indices.size()));
        }
      }
    }
    // vt, vn, vp, g, o, s, usemtl, mtllib, p and unknown keywords carry no geometry we use.
  }
  const int64_t nv = static_cast<int64_t>(xyz.size() / 3);
  for (size_t k = 0; k < forward.size(); ++k)
    if (forward[k].second >= nv)
      fail_line(name, forward[k].first, std::string(forward_line[k] ? "line" : "face") + " vertex index " +
                                            std::to_string(forward[k].second + 1) + " is out of range (the file has " +
                                            std::to_string(nv) + " vertices)");
  return finish(xyz, offsets, indices, name);
}

// ------------------------------------------------------------------ writing

namespace io_detail {

std::string write_obj(const PolygonMesh& mesh) {
  std::string out = "# written by LARAP\n";
  out.reserve(static_cast<size_t>(mesh.num_vertices()) * 60 + mesh.face_indices.size() * 9);
  for (int64_t i = 0; i < mesh.num_vertices(); ++i) {
    out += "v ";
    put_vertex(out, mesh, i);
    out += '\n';
  }
  for (int64_t f = 0; f < mesh.num_faces(); ++f) {
    const int64_t b = mesh.face_offsets[f];
    const bool edge = mesh.face_offsets[f + 1] - b == 2 && mesh.face_indices[b] != mesh.face_indices[b + 1];
    out += edge ? 'l' : 'f';  // a loose edge (`l 3 3` is not a line: kept as the face it was)
    for (int64_t k = mesh.face_offsets[f]; k < mesh.face_offsets[f + 1]; ++k) {
      out += ' ';
      put_int(out, mesh.face_indices[k] + 1);
    }
    out += '\n';
  }
  return out;
}

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

}  // namespace io_detail
}  // namespace larap
