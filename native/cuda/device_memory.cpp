#include "device_memory.h"

#include <larap/errors.h>

#include <atomic>
#include <cstdlib>
#include <string>

namespace larap {
namespace cuda {
namespace {

std::atomic<size_t> g_device_bytes{0};

}  // namespace

void fail(cudaError_t e, const char* what) {
  cudaGetLastError();  // clear a non-sticky error so that the process can go on
  const std::string msg =
      std::string("CUDA error in ") + what + ": " + cudaGetErrorName(e) + " (" + cudaGetErrorString(e) + ")";
  if (e == cudaErrorMemoryAllocation) throw OutOfMemory("device out of memory: " + msg);
  throw DeviceError(msg);
}

void* device_alloc(size_t bytes) {
  const char* lim = std::getenv("LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES");
  if (lim && *lim) {
    const unsigned long long limit = std::strtoull(lim, nullptr, 10);
    if (g_device_bytes.load() + bytes > limit)
      throw OutOfMemory("device out of memory: cannot allocate " + std::to_string(bytes) + " bytes (" +
                        std::to_string(g_device_bytes.load()) +
                        " in use; simulated by "
                        "LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES=" +
                        lim + ")");
  }
  void* q = nullptr;
  const cudaError_t e = cudaMalloc(&q, bytes);
  if (e != cudaSuccess) {
    cudaGetLastError();
    if (e == cudaErrorMemoryAllocation)
      throw OutOfMemory("device out of memory: cannot allocate " + std::to_string(bytes) + " bytes");
    fail(e, "cudaMalloc");
  }
  g_device_bytes += bytes;
  return q;
}

void device_free(void* p, size_t bytes) {
  cudaFree(p);
  g_device_bytes -= bytes;
}

size_t device_bytes_in_use() { return g_device_bytes.load(); }

void* pinned_alloc(size_t bytes) {
  void* q = nullptr;
  const cudaError_t e = cudaMallocHost(&q, bytes);
  if (e != cudaSuccess) {
    cudaGetLastError();
    if (e == cudaErrorMemoryAllocation)
      throw OutOfMemory("out of pinned host memory: cannot allocate " + std::to_string(bytes) + " bytes");
    fail(e, "cudaMallocHost");
  }
  return q;
}

float elapsed_ms(const Event& from, const Event& to) {
  float ms = 0.f;
  LARAP_CUDA_CHECK(cudaEventElapsedTime(&ms, from.get(), to.get()));
  return ms;
}

}  // namespace cuda
}  // namespace larap
