// Exception types of the LARAP engine. Every failure the engine can detect is one of these; the
// Python module maps each to a fitting Python exception (see python/src/module.cpp).
#pragma once
#include <stdexcept>
#include <string>

namespace larap {

// Bad value from the caller (shape, range, NaN, ...): Python ValueError.
struct InvalidInput : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

// A file's contents are malformed (truncated, wrong format, lying counts): Python ValueError.
struct ParseError : InvalidInput {
  using InvalidInput::InvalidInput;
};

// A file does not exist: Python FileNotFoundError.
struct FileNotFound : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Any other I/O failure (permissions, disk full): Python OSError.
struct IOFailure : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The request needs more memory than is available (host or device): Python MemoryError.
struct OutOfMemory : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Calls in the wrong order (solve before set_handles, ...): Python RuntimeError.
struct StateError : std::logic_error {
  using std::logic_error::logic_error;
};

// A backend is not available (CUDA not built, no GPU) or failed: Python RuntimeError.
struct DeviceError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace larap
