// libFuzzer target for the OBJ reader. Malformed input must end in a larap exception; any other
// exception, a crash or a sanitizer report is a finding. Run through scripts/fuzz.
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include <cstddef>
#include <cstdint>
#include <string_view>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const larap::PolygonMesh mesh =
        larap::parse_obj(std::string_view(reinterpret_cast<const char*>(data), size), "fuzz.obj");
    // A mesh that parsed must be consistent: every face index in range.
    for (const int64_t v : mesh.face_indices)
      if (v < 0 || v >= mesh.num_vertices()) __builtin_trap();
  } catch (const larap::ParseError&) {  // the only acceptable failure
  }
  return 0;
}
