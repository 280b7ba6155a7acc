// The compiled half of the `larap` package. One bind_<area>() per file; the numpy-facing,
// documented API lives in python/larap/*.py.
#include <larap/errors.h>
#include <pybind11/pybind11.h>

namespace py = pybind11;

void bind_deformer(py::module_& m);
void bind_io(py::module_& m);

PYBIND11_MODULE(_core, m) {
  m.doc() = "LARAP native engine (use the `larap` package, not this module directly)";
  m.attr("__version__") = LARAP_VERSION;
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const larap::FileNotFound& e) {
      PyErr_SetString(PyExc_FileNotFoundError, e.what());
    } catch (const larap::IOFailure& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const larap::InvalidInput& e) {  // ParseError included
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const larap::OutOfMemory& e) {
      PyErr_SetString(PyExc_MemoryError, e.what());
    } catch (const larap::StateError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    } catch (const larap::DeviceError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    }
  });
  bind_deformer(m);
  bind_io(m);
}
