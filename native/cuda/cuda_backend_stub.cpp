// Without the CUDA part, device="cuda" fails clearly; with it, native/cuda defines these.
#ifndef LARAP_WITH_CUDA
#include <larap/errors.h>

#include "backend.h"

namespace larap {

std::unique_ptr<Backend> make_cuda_backend(const Lattice&, const RowMatrixX3d&) {
  throw DeviceError(
      "device 'cuda' is not available: this build of larap has no CUDA support "
      "(nvcc was not found when it was built)");
}

bool cuda_available(std::string* why) {
  if (why) *why = "this build of larap has no CUDA support";
  return false;
}

}  // namespace larap
#endif
