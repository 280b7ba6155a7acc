// Reading and writing meshes: Wavefront OBJ, PLY (ASCII and binary little/big endian), OFF.
// Every reader refuses malformed input with larap::ParseError ("file:line: what is wrong"), a missing
// file with larap::FileNotFound, and never allocates more than the input can justify (a header that
// claims 10^12 vertices in a 1 kB file is an error, not an allocation).
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
// `ascii` is set). When `template_obj` names an OBJ file whose vertex count equals the mesh's, and
// the output is OBJ, the template is copied line by line with only the `v` positions replaced, so
// UVs, normals, groups, materials and the face structure are kept.
void save_mesh(const std::string& path, const PolygonMesh& mesh, bool ascii = false,
               const std::string& template_obj = "");

}  // namespace larap
