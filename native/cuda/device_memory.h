// Device memory and CUDA handles for the CUDA backend (host side): every CUDA error mapped to a
// larap exception, RAII owners of device and pinned buffers, events, a stream and a graph, and
// the accounting of live device bytes with its fault injection for tests.
//
// Errors: a failed CUDA call throws larap::DeviceError naming the call and CUDA's message;
// cudaErrorMemoryAllocation (device or pinned) throws larap::OutOfMemory. Non-sticky errors are
// cleared first, so the process goes on.
//
// Fault injection (tests/python/test_cuda.py, the out-of-memory tests): with the environment
// variable LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES=N, read at every device allocation, an allocation
// that would take the process's live device bytes (every DeviceBuffer, counted on allocation and
// free) over N fails exactly like cudaErrorMemoryAllocation, with a message naming the variable.
// It is the backend's only environment read besides the options (cuda_options.h).
#pragma once
#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>

namespace larap {
namespace cuda {

// Throws the larap exception for e (after clearing a non-sticky error); `what`: the call.
[[noreturn]] void fail(cudaError_t e, const char* what);

#define LARAP_CUDA_CHECK(call)                                             \
  do {                                                                     \
    const cudaError_t larap_err_ = (call);                                 \
    if (larap_err_ != cudaSuccess) ::larap::cuda::fail(larap_err_, #call); \
  } while (0)

// cudaMalloc with the accounting and the fault injection above; freed by device_free.
void* device_alloc(size_t bytes);
void device_free(void* p, size_t bytes);
// Live device bytes of the process (every DeviceBuffer).
size_t device_bytes_in_use();
// cudaMallocHost; throws OutOfMemory when pinned memory runs out.
void* pinned_alloc(size_t bytes);

// Where a growing buffer lives: device memory (with the accounting above) or page-locked host
// memory (for asynchronous copies).
struct DeviceMemory {
  static void* alloc(size_t bytes) { return device_alloc(bytes); }
  static void free(void* p, size_t bytes) { device_free(p, bytes); }
};
struct PinnedMemory {
  static void* alloc(size_t bytes) { return pinned_alloc(bytes); }
  static void free(void* p, size_t /*bytes*/) { cudaFreeHost(p); }
};

// An array of T in `Memory` that grows on demand (contents are not kept when it grows).
template <typename T, typename Memory>
class GrowingBuffer {
 public:
  GrowingBuffer() = default;
  GrowingBuffer(const GrowingBuffer&) = delete;
  GrowingBuffer& operator=(const GrowingBuffer&) = delete;
  ~GrowingBuffer() { release(); }
  void release() {
    if (p_) Memory::free(p_, cap_ * sizeof(T));
    p_ = nullptr;
    cap_ = 0;
  }
  // At least n elements.
  T* reserve(size_t n) {
    if (n <= cap_ && p_) return p_;
    release();
    const size_t cap = std::max<size_t>(n, 1);
    p_ = static_cast<T*>(Memory::alloc(cap * sizeof(T)));
    cap_ = cap;
    return p_;
  }
  T* get() const { return p_; }
  size_t size() const { return cap_; }

 protected:
  T* p_ = nullptr;
  size_t cap_ = 0;
};

// A device array of T that grows on demand, with an upload.
template <typename T>
class DeviceBuffer : public GrowingBuffer<T, DeviceMemory> {
 public:
  // reserve(n), then an asynchronous copy of src[0, n) on stream st (src must live until then).
  T* upload(const T* src, size_t n, cudaStream_t st) {
    T* p = this->reserve(n);
    if (n) LARAP_CUDA_CHECK(cudaMemcpyAsync(p, src, n * sizeof(T), cudaMemcpyHostToDevice, st));
    return p;
  }
};

// Page-locked host memory (for asynchronous copies), grows on demand.
template <typename T>
using PinnedBuffer = GrowingBuffer<T, PinnedMemory>;

class Event {
 public:
  Event() { LARAP_CUDA_CHECK(cudaEventCreate(&e_)); }
  Event(const Event&) = delete;
  Event& operator=(const Event&) = delete;
  ~Event() {
    if (e_) cudaEventDestroy(e_);
  }
  cudaEvent_t get() const { return e_; }

 private:
  cudaEvent_t e_ = nullptr;
};

// Milliseconds between two recorded events.
float elapsed_ms(const Event& from, const Event& to);

// A non-blocking stream; synchronised before it is destroyed.
class Stream {
 public:
  Stream() { LARAP_CUDA_CHECK(cudaStreamCreateWithFlags(&s_, cudaStreamNonBlocking)); }
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  ~Stream() {
    if (s_) {
      cudaStreamSynchronize(s_);
      cudaStreamDestroy(s_);
    }
  }
  operator cudaStream_t() const { return s_; }

 private:
  cudaStream_t s_ = nullptr;
};

// An instantiated CUDA graph.
class GraphExec {
 public:
  GraphExec() = default;
  GraphExec(const GraphExec&) = delete;
  GraphExec& operator=(const GraphExec&) = delete;
  ~GraphExec() { reset(); }
  void reset() {
    if (exec_) cudaGraphExecDestroy(exec_);
    exec_ = nullptr;
  }
  void set(cudaGraphExec_t e) {
    reset();
    exec_ = e;
  }
  cudaGraphExec_t get() const { return exec_; }

 private:
  cudaGraphExec_t exec_ = nullptr;
};

}  // namespace cuda
}  // namespace larap
