// Mesh files on disk: the format from the extension (format_from_path), load_mesh and save_mesh
// dispatching to the readers and writers of obj.cpp, ply.cpp and off.cpp, reading a whole file,
// and writing one atomically (through `path.tmp` and a rename).
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include "writers.h"

#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>

namespace larap {
using namespace io_detail;

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
