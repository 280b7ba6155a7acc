// pybind11 binding of larap::Deformer. Inputs arrive already validated and converted by
// python/larap/deformer.py; the checks here guard the memory accesses only.
#include <larap/deformer.h>
#include <larap/errors.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstring>
#include <mutex>

#include "parallel.h"

namespace py = pybind11;
using larap::RowMatrixX3d;

namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;
using I64 = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

void require_rows3(const py::buffer_info& info, const char* what, int64_t rows) {
  if (info.ndim != 2 || info.shape[1] != 3 || (rows >= 0 && info.shape[0] != rows))
    throw larap::InvalidInput(std::string(what) + " must have shape (" +
                              (rows >= 0 ? std::to_string(rows) : std::string("n")) + ", 3)");
}

py::array_t<double> to_numpy(const RowMatrixX3d& M) {
  py::array_t<double> a({M.rows(), Eigen::Index(3)});
  if (M.size()) std::memcpy(a.mutable_data(), M.data(), sizeof(double) * M.size());
  return a;
}

std::unique_ptr<larap::Deformer> make(F64 vertices, I64 offsets, I64 indices, int64_t cells,
                                      double cell_size, const std::string& weights, double gamma,
                                      const std::string& device, int64_t max_bytes, int levels) {
  const auto vi = vertices.request();
  require_rows3(vi, "vertices", -1);
  larap::PolygonMesh mesh;
  mesh.vertices = Eigen::Map<const RowMatrixX3d>(vertices.data(), vi.shape[0], 3);
  mesh.face_offsets.assign(offsets.data(), offsets.data() + offsets.size());
  mesh.face_indices.assign(indices.data(), indices.data() + indices.size());
  if (mesh.face_offsets.empty()) mesh.face_offsets.push_back(0);
  larap::DeformerOptions opt;
  opt.lattice.cells = cells;
  opt.lattice.cell_size = cell_size;
  opt.lattice.max_bytes = max_bytes;
  opt.weights = larap::parse_weight_kind(weights);
  opt.gamma = gamma;
  opt.device = device;
  opt.levels = levels;
  py::gil_scoped_release release;
  return std::make_unique<larap::Deformer>(std::move(mesh), opt);
}

py::array solve(larap::Deformer& d, F64 targets, int iterations, py::object out, double tolerance) {
  const int64_t m = static_cast<int64_t>(d.handles().size());
  const int64_t n = d.mesh().num_vertices();
  require_rows3(targets.request(), "targets", m);
  py::array result;
  if (out.is_none()) {
    result = py::array_t<double>({n, int64_t(3)});
  } else {
    result = out.cast<py::array>();
    const auto info = result.request(true);
    require_rows3(info, "out", n);
    if (!(result.flags() & py::array::c_style))
      throw larap::InvalidInput("out must be C-contiguous");
    if (!result.writeable()) throw larap::InvalidInput("out must be writeable");
  }
  const double* t = targets.data();
  if (py::isinstance<py::array_t<float>>(result) && result.dtype().is(py::dtype::of<float>())) {
    float* o = static_cast<float*>(result.mutable_data());
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(d.mutex());
    d.solve(t, iterations, o, tolerance);
  } else if (result.dtype().is(py::dtype::of<double>())) {
    double* o = static_cast<double*>(result.mutable_data());
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(d.mutex());
    d.solve(t, iterations, o, tolerance);
  } else {
    throw larap::InvalidInput("out must be a float32 or float64 array");
  }
  return result;
}

// Positions left on the GPU: a (n, 3) float32 array in device memory owned by the Deformer,
// valid until its next solve. Exposes __cuda_array_interface__ (CuPy, PyTorch, Numba read it
// without a copy).
struct DeviceArray {
  uintptr_t ptr = 0;
  int64_t rows = 0;
  py::object owner;  // keeps the Deformer alive
};

DeviceArray solve_on_device(py::object self, F64 targets, int iterations, double tolerance) {
  auto& d = self.cast<larap::Deformer&>();
  const int64_t m = static_cast<int64_t>(d.handles().size());
  require_rows3(targets.request(), "targets", m);
  const double* t = targets.data();
  const float* p = nullptr;
  {
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(d.mutex());
    p = d.solve_on_device(t, iterations, tolerance);
  }
  return DeviceArray{reinterpret_cast<uintptr_t>(p), d.mesh().num_vertices(), self};
}

py::dict stats(const larap::Deformer& d) {
  larap::SolveStats s;
  {
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(d.mutex());
    s = d.stats();
  }
  py::dict r;
  r["energy"] = s.energy;
  r["iterations"] = s.iterations;
  r["rigid_carry"] = s.rigid_carry;
  r["ms_rotations"] = s.ms_rotations;
  r["ms_rhs"] = s.ms_rhs;
  r["ms_solve"] = s.ms_solve;
  r["ms_transfer"] = s.ms_transfer;
  r["ms_total"] = s.ms_total;
  r["ms_energy"] = s.ms_energy;
  r["ms_start"] = s.ms_start;
  r["ms_coarse"] = s.ms_coarse;
  r["ms_factorize"] = s.ms_factorize;
  r["ms_lattice"] = s.ms_lattice;
  r["ms_binding"] = s.ms_binding;
  return r;
}

}  // namespace

void bind_deformer(py::module_& m) {
  py::class_<larap::Deformer>(m, "Deformer")
      .def(py::init(&make), py::arg("vertices"), py::arg("face_offsets"), py::arg("face_indices"),
           py::arg("cells") = 0, py::arg("cell_size") = 0.0, py::arg("weights") = "trilinear",
           py::arg("gamma") = 0.1, py::arg("device") = "cpu", py::arg("max_bytes") = 0,
           py::arg("levels") = 1)
      .def("set_handles",
           [](larap::Deformer& d, I64 idx) {
             std::vector<int64_t> v(idx.data(), idx.data() + idx.size());
             py::gil_scoped_release release;
             std::lock_guard<std::mutex> lock(d.mutex());
             d.set_handles(v);
           })
      .def("solve", &solve, py::arg("targets"), py::arg("iterations") = 5, py::arg("out") = py::none(),
           py::arg("tolerance") = 0.0)
      .def("solve_on_device", &solve_on_device, py::arg("targets"), py::arg("iterations") = 5,
           py::arg("tolerance") = 0.0)
      .def("reset", [](larap::Deformer& d) {
        py::gil_scoped_release release;
        std::lock_guard<std::mutex> lock(d.mutex());
        d.reset();
      })
      .def_property(
          "weights", [](const larap::Deformer& d) { return std::string(larap::weight_kind_name(d.weights())); },
          [](larap::Deformer& d, const std::string& w) {
            const auto k = larap::parse_weight_kind(w);
            py::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(d.mutex());
            d.set_weights(k);
          })
      .def_property("gamma", &larap::Deformer::gamma, [](larap::Deformer& d, double g) {
        py::gil_scoped_release release;
        std::lock_guard<std::mutex> lock(d.mutex());
        d.set_gamma(g);
      })
      .def_property_readonly("num_vertices", [](const larap::Deformer& d) { return d.mesh().num_vertices(); })
      .def_property_readonly("num_nodes", [](const larap::Deformer& d) { return d.lattice().num_nodes(); })
      .def_property_readonly("num_cells", [](const larap::Deformer& d) { return d.lattice().num_cells(); })
      .def_property_readonly("num_components", [](const larap::Deformer& d) { return d.lattice().num_components; })
      .def_property_readonly("cell_size", [](const larap::Deformer& d) { return d.lattice().h; })
      .def_property_readonly("diagonal", &larap::Deformer::diagonal)
      .def_property_readonly("levels", &larap::Deformer::levels)
      .def_property_readonly("device", &larap::Deformer::device)
      .def_property_readonly("fallback_reason", &larap::Deformer::fallback_reason)
      .def_property_readonly("handles", [](const larap::Deformer& d) {
        return py::array_t<int64_t>(py::ssize_t(d.handles().size()), d.handles().data());
      })
      .def_property_readonly("stats", &stats)
      .def("lattice_rest", [](const larap::Deformer& d) { return to_numpy(d.lattice().rest); })
      .def("lattice_deformed", [](const larap::Deformer& d) {
        larap::RowMatrixX3d p;
        {
          py::gil_scoped_release release;
          std::lock_guard<std::mutex> lock(d.mutex());
          p = d.lattice_deformed();
        }
        return to_numpy(p);
      })
      .def("lattice_edges", [](const larap::Deformer& d) {
        const auto& e = d.lattice().edges;
        py::array_t<int32_t> a({py::ssize_t(e.size()), py::ssize_t(2)});
        if (!e.empty()) std::memcpy(a.mutable_data(), e.data(), sizeof(int32_t) * 2 * e.size());
        return a;
      })
      .def("cell_kinds", [](const larap::Deformer& d) {
        const auto& k = d.lattice().cell_kind;
        return py::array_t<uint8_t>(py::ssize_t(k.size()), k.data());
      })
      .def("cell_coords", [](const larap::Deformer& d) {
        const auto& c = d.lattice().cell_coords;
        py::array_t<int32_t> a({py::ssize_t(c.size()), py::ssize_t(3)});
        for (size_t i = 0; i < c.size(); ++i)
          for (int k = 0; k < 3; ++k) a.mutable_at(i, k) = c[i][k];
        return a;
      })
      .def_property_readonly("origin", [](const larap::Deformer& d) {
        return py::make_tuple(d.lattice().origin.x(), d.lattice().origin.y(), d.lattice().origin.z());
      })
      .def("binding_weights", [](const larap::Deformer& d, int64_t v) {
        if (v < 0 || v >= d.mesh().num_vertices()) throw larap::InvalidInput("vertex out of range");
        const auto& b = d.binding();
        std::vector<int32_t> ids(b.stencil_size());
        std::vector<double> w(b.stencil_size());
        b.weights_of(d.lattice(), v, ids.data(), w.data());
        return py::make_tuple(ids, w);
      });
  py::class_<DeviceArray>(m, "DeviceArray")
      .def_property_readonly("ptr", [](const DeviceArray& a) { return a.ptr; })
      .def_property_readonly("shape", [](const DeviceArray& a) { return py::make_tuple(a.rows, 3); })
      .def_property_readonly("dtype", [](const DeviceArray&) { return py::dtype::of<float>(); })
      .def_property_readonly("__cuda_array_interface__", [](const DeviceArray& a) {
        py::dict d;
        d["shape"] = py::make_tuple(a.rows, 3);
        d["typestr"] = "<f4";
        d["data"] = py::make_tuple(a.ptr, false);
        d["version"] = 3;
        d["strides"] = py::none();
        // Written on the engine's stream and synchronised before solve_on_device returns.
        d["stream"] = py::none();
        return d;
      })
      .def("__repr__", [](const DeviceArray& a) {
        return "<larap.DeviceArray (" + std::to_string(a.rows) + ", 3) float32 on the GPU>";
      });
  m.def("available_devices", &larap::available_devices);
  m.def("set_num_threads", [](int n) {
    if (n < 0) throw larap::InvalidInput("the number of threads must be >= 0 (0 = all cores), got " + std::to_string(n));
    larap::set_num_threads(n);
  }, py::arg("n"));
  m.def("num_threads", &larap::num_threads);
}
