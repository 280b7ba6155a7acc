// Reading and writing meshes: Wavefront OBJ, PLY (ASCII and binary little/big endian), OFF.
// Every reader refuses malformed input with larap::ParseError ("file:line: what is wrong"; binary
// PLY says "file:byte N: ..."), a missing file with larap::FileNotFound, and never allocates more
// than the input can justify (a header that claims 10^12 vertices in a 1 kB file is an error, not
// an allocation). A parsed mesh has passed validate_mesh: at least one vertex, finite coordinates,
// indices in range. Files without faces (point clouds) are valid.
//
// Accepted: OBJ `v` (extra values such as colours ignored) and `f` in the forms v, v/vt, v//vn,
// v/vt/vn with 1-based or negative (relative) indices, `\` line continuations, other statements
// ignored. PLY `element vertex` with scalar x, y, z of any type and `element face` with a
// `vertex_indices` (or `vertex_index`) integer list; other properties and elements are skipped.
// OFF, COFF, NOFF, STOFF... with the counts on the magic line or the next; trailing values ignored.
#pragma once
#include <larap/mesh.h>
#include <string>
#include <string_view>

namespace larap {

enum class MeshFormat { OBJ, PLY, OFF };

// Format from the file name's extension (case-insensitive); throws InvalidInput for anything else.
MeshFormat format_from_path(const std::string& path);

// Parse a whole file's contents held in memory. `name` is used in error messages only.
PolygonMesh parse_obj(std::string_view data, const std::string& name = "<memory>");
PolygonMesh parse_ply(std::string_view data, const std::string& name = "<memory>");
PolygonMesh parse_off(std::string_view data, const std::string& name = "<memory>");

PolygonMesh load_mesh(const std::string& path);

// Write `mesh` in the format the extension names (PLY is written binary little endian unless
// `ascii` is set; doubles for x, y, z and an int32 index list). Positions are written so that they
// read back bit-exactly. When `template_obj` names an OBJ file whose vertex count equals the
// mesh's, and the output is OBJ, the template is copied line by line with only the `v` positions
// replaced (values after xyz kept), so UVs, normals, groups, materials and the face structure are
// kept; with another vertex count a plain OBJ is written; a missing template is FileNotFound.
// The file is written to `path + ".tmp"` and renamed over `path`, so a failure (IOFailure) never
// leaves a half-written file; an invalid mesh is InvalidInput before anything is written.
void save_mesh(const std::string& path, const PolygonMesh& mesh, bool ascii = false,
               const std::string& template_obj = "");

}  // namespace larap
