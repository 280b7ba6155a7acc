// Exception types of the LARAP engine. Every failure the engine can detect is one of these; the
// Python module maps each to a fitting Python exception (see python/src/module.cpp).
#pragma once
#include <cmath>
#include <cstdio>
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

// A number as the messages of these exceptions write it: six significant digits ("1e-07",
// "0.03", "-2.5e+300", "nan"), where std::to_string would write 1e-7 as "0.000000".
inline std::string number_text(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

// A size in bytes as the messages of OutOfMemory write it: "812 B", "12.3 KiB", "45.0 MiB",
// "1.9 GiB", "3.0 TiB" (three significant digits or more, so a small limit never reads "0 MiB").
inline std::string memory_text(double bytes) {
  static const char* const units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  int u = 0;
  while (u < 4 && std::abs(bytes) >= 1024.0) {
    bytes /= 1024.0;
    ++u;
  }
  char buf[64];
  std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.1f %s", bytes, units[u]);
  return buf;
}

// Calls in the wrong order (solve before set_handles, ...): Python RuntimeError.
struct StateError : std::logic_error {
  using std::logic_error::logic_error;
};

// A backend is not available (CUDA not built, no GPU) or failed: Python RuntimeError.
struct DeviceError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace larap
