// The per-format writers behind save_mesh (files.cpp). Each returns the whole file's bytes for a
// mesh that has passed validate_mesh; positions are written so that they read back bit-exactly.
// Internal: larap::io_detail is no public API.
#pragma once
#include <larap/mesh.h>

#include <string>
#include <string_view>

namespace larap::io_detail {

// Plain OBJ: a comment, one `v` line per vertex, one `f` line per face with 1-based indices (obj.cpp).
std::string write_obj(const PolygonMesh& mesh);
// The template with each `v` line's xyz replaced; empty when its vertex count differs (obj.cpp).
std::string write_obj_from_template(const PolygonMesh& mesh, std::string_view tpl);
// PLY, binary little endian or `ascii`; throws InvalidInput past int32 vertex indices (ply.cpp).
std::string write_ply(const PolygonMesh& mesh, bool ascii);
// OFF with the counts on the line after the magic (off.cpp).
std::string write_off(const PolygonMesh& mesh);

}  // namespace larap::io_detail
