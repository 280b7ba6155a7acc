// pybind11 binding of larap::Deformer. Inputs arrive converted by python/larap/deformer.py
// (types, shapes) and the engine checks their values; the checks here guard memory accesses only.
// Python threads may share one Deformer: every call runs with the GIL released under the
// instance's own lock (PyDeformer::locked), so calls on one instance are serialised.
#include <larap/deformer.h>
#include <larap/errors.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstring>
#include <limits>
#include <mutex>

#include "parallel.h"

namespace py = pybind11;
using larap::RowMatrixX3d;

namespace {

// The engine object plus the lock that serialises the calls of Python threads on it.
struct PyDeformer {
  larap::Deformer engine;
  mutable std::mutex mutex;
  PyDeformer(larap::PolygonMesh mesh, const larap::DeformerOptions& options)
      : engine(std::move(mesh), options) {}

  // f(engine) with the GIL released and this instance locked.
  template <typename F>
  auto locked(F&& f) {
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(mutex);
    return f(engine);
  }
  template <typename F>
  auto locked(F&& f) const {
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> lock(mutex);
    return f(static_cast<const larap::Deformer&>(engine));
  }
};

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

// Research hook (scripts/experiments/branch_engine.py): a dict of the copies' arrays (cell_coords
// (C, 3), cell_nodes (C, 8) node labels, cell_kind (C,), cell_weight (C,) or empty, vertex_cell
// (V,), couplings (K, 2) branch and trunk copies, coupling_weights (K,)) that replaces the fine
// lattice's copies on the same grid (Lattice::replace_copies).
std::function<void(larap::Lattice&)> copies_edit(const py::object& obj) {
  const py::dict d = obj.cast<py::dict>();
  using I32 = py::array_t<int32_t, py::array::c_style | py::array::forcecast>;
  auto arr = [&](const char* key) { return I32(d[key]); };
  larap::LatticeCopies k;
  for (const char* key : {"cell_coords", "cell_nodes", "vertex_cell", "couplings"}) {  // no silent narrowing
    const auto a = py::array_t<int64_t, py::array::c_style | py::array::forcecast>(d[key]);
    for (py::ssize_t j = 0; j < a.size(); ++j)
      if (a.data()[j] < std::numeric_limits<int32_t>::min() || a.data()[j] > std::numeric_limits<int32_t>::max())
        throw larap::InvalidInput(std::string("lattice_copies: ") + key + " holds a value beyond 32 bits");
  }
  const I32 coords = arr("cell_coords"), nodes = arr("cell_nodes"), verts = arr("vertex_cell"), pairs = arr("couplings");
  if (coords.ndim() != 2 || coords.shape(1) != 3 || nodes.ndim() != 2 || nodes.shape(1) != 8 ||
      pairs.ndim() != 2 || pairs.shape(1) != 2)
    throw larap::InvalidInput("lattice_copies: cell_coords must be (C, 3), cell_nodes (C, 8), couplings (K, 2)");
  const py::array_t<uint8_t, py::array::c_style | py::array::forcecast> kinds(d["cell_kind"]);
  const F64 weights(d["cell_weight"]), cw(d["coupling_weights"]);
  const size_t nc = size_t(kinds.size());
  if (size_t(coords.size()) != 3 * nc || size_t(nodes.size()) != 8 * nc || size_t(pairs.size()) != 2 * size_t(cw.size()))
    throw larap::InvalidInput("lattice_copies: arrays of the wrong sizes");
  for (size_t c = 0; c < nc; ++c) {
    k.cell_coords.emplace_back(coords.data()[3 * c], coords.data()[3 * c + 1], coords.data()[3 * c + 2]);
    std::array<int32_t, 8> n{};
    for (size_t q = 0; q < 8; ++q) n[q] = nodes.data()[8 * c + q];
    k.cell_nodes.push_back(n);
  }
  k.cell_kind.assign(kinds.data(), kinds.data() + nc);
  k.cell_weight.assign(weights.data(), weights.data() + weights.size());
  k.vertex_cell.assign(verts.data(), verts.data() + verts.size());
  for (py::ssize_t j = 0; j < cw.size(); ++j)
    k.couplings.push_back({pairs.data()[2 * j], pairs.data()[2 * j + 1], cw.data()[j]});
  return [k = std::move(k)](larap::Lattice& lat) { lat.replace_copies(k); };
}

std::unique_ptr<PyDeformer> make(F64 vertices, I64 offsets, I64 indices, int64_t cells,
                                      double cell_size, const std::string& weights, double gamma,
                                      const std::string& device, int64_t max_bytes, int levels,
                                      bool split_cells, int split_resolution, double junction_brace,
                                      py::object lattice_copies, bool branch_copies, double branch_coupling) {
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
  opt.lattice.split_cells = split_cells;
  opt.lattice.split_resolution = split_resolution;
  opt.lattice.branch_copies = branch_copies;
  opt.lattice.branch_coupling = branch_coupling;
  opt.weights = larap::parse_weight_kind(weights);
  opt.gamma = gamma;
  opt.device = device;
  opt.levels = levels;
  opt.junction_brace = junction_brace;
  if (!lattice_copies.is_none()) opt.lattice.edit = copies_edit(lattice_copies);
  py::gil_scoped_release release;
  return std::make_unique<PyDeformer>(std::move(mesh), opt);
}

// The targets of a pose: (m, 3) row targets, or with `transforms` (G, 4, 4) group maps. Their
// shape is read with the GIL held and checked under the instance's lock, in the same locked call
// that reads them: another thread's set_handles or set_handle_groups may change the handle count
// in between (a check made before locking let a solve read past the end of its targets).
struct TargetShape {
  py::ssize_t ndim;
  py::ssize_t shape[3];
  bool transforms;
};

TargetShape shape_of(const F64& targets, bool transforms) {
  const auto info = targets.request();
  TargetShape s{info.ndim, {0, 0, 0}, transforms};
  for (py::ssize_t k = 0; k < info.ndim && k < 3; ++k) s.shape[k] = info.shape[k];
  return s;
}

std::string shape_text(const TargetShape& s) {
  std::string t = "(";
  for (py::ssize_t k = 0; k < s.ndim && k < 3; ++k) t += (k ? ", " : "") + std::to_string(s.shape[k]);
  return t + (s.ndim == 1 ? ",)" : s.ndim > 3 ? ", ...)" : ")");
}

void check_targets(const larap::Deformer& d, const TargetShape& s) {
  if (!s.transforms) {
    const int64_t m = static_cast<int64_t>(d.handles().size());
    if (s.ndim != 2 || s.shape[1] != 3 || s.shape[0] != m)
      throw larap::InvalidInput("targets should have shape (" + std::to_string(m) + ", 3), shape is " +
                                shape_text(s) + " (the handles changed?)");
    return;
  }
  const int64_t G = d.num_groups();
  if (s.ndim != 3 || s.shape[0] != G || s.shape[1] != 4 || s.shape[2] != 4)
    throw larap::InvalidInput("transforms should have shape (" + std::to_string(G) + ", 4, 4), shape is " +
                              shape_text(s) + " (the handle groups changed?)");
}

py::array solve(PyDeformer& self, F64 targets, int iterations, py::object out, double tolerance,
                bool transforms) {
  const larap::Deformer& d = self.engine;
  const int64_t n = d.mesh().num_vertices();  // the mesh never changes
  const TargetShape shape = shape_of(targets, transforms);
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
    self.locked([&](larap::Deformer& e) {
      check_targets(e, shape);
      transforms ? e.solve_transforms(t, iterations, o, tolerance) : e.solve(t, iterations, o, tolerance);
    });
  } else if (result.dtype().is(py::dtype::of<double>())) {
    double* o = static_cast<double*>(result.mutable_data());
    self.locked([&](larap::Deformer& e) {
      check_targets(e, shape);
      transforms ? e.solve_transforms(t, iterations, o, tolerance) : e.solve(t, iterations, o, tolerance);
    });
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

DeviceArray solve_on_device(py::object owner, F64 targets, int iterations, double tolerance,
                            bool transforms) {
  auto& self = owner.cast<PyDeformer&>();
  const TargetShape shape = shape_of(targets, transforms);
  const double* t = targets.data();
  const float* p = self.locked([&](larap::Deformer& e) {
    check_targets(e, shape);
    return e.solve_on_device(t, iterations, tolerance, transforms);
  });
  return DeviceArray{reinterpret_cast<uintptr_t>(p), self.engine.mesh().num_vertices(), owner};
}

py::dict stats(const PyDeformer& self) {
  const larap::SolveStats s = self.locked([](const larap::Deformer& e) { return e.stats(); });
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
  using D = larap::Deformer;
  py::class_<PyDeformer>(m, "Deformer")
      .def(py::init(&make), py::arg("vertices"), py::arg("face_offsets"), py::arg("face_indices"),
           py::arg("cells") = 0, py::arg("cell_size") = 0.0, py::arg("weights") = "trilinear",
           py::arg("gamma") = larap::DeformerOptions{}.gamma, py::arg("device") = "cpu", py::arg("max_bytes") = 0,
           py::arg("levels") = 1, py::arg("split_cells") = true, py::arg("split_resolution") = 24,
           py::arg("junction_brace") = larap::DeformerOptions{}.junction_brace,
           py::arg("lattice_copies") = py::none(), py::arg("branch_copies") = false,
           py::arg("branch_coupling") = larap::LatticeOptions{}.branch_coupling)
      .def("set_handles",
           [](PyDeformer& self, I64 idx) {
             std::vector<int64_t> v(idx.data(), idx.data() + idx.size());
             self.locked([&](D& d) { d.set_handles(v); });
           })
      .def("set_handle_groups",
           // Groups as flat arrays: group g is ids[offsets[g]:offsets[g+1]]; weights (G,) or
           // empty; vertex_weights aligned with ids, or empty.
           [](PyDeformer& self, I64 ids, I64 offsets, F64 weights, F64 vertex_weights) {
             const int64_t* o = offsets.data();
             const int64_t G = offsets.size() - 1, total = ids.size();
             if (G < 0 || o[0] != 0 || o[G] != total)
               throw larap::InvalidInput("group offsets must run from 0 to the number of ids");
             if (vertex_weights.size() != 0 && vertex_weights.size() != total)
               throw larap::InvalidInput("vertex_weights must hold one weight per handle vertex");
             std::vector<std::vector<int64_t>> groups(static_cast<size_t>(G));
             std::vector<std::vector<double>> vw(vertex_weights.size() ? size_t(G) : 0);
             for (int64_t g = 0; g < G; ++g) {
               if (o[g + 1] < o[g]) throw larap::InvalidInput("group offsets must not decrease");
               groups[g].assign(ids.data() + o[g], ids.data() + o[g + 1]);
               if (!vw.empty()) vw[g].assign(vertex_weights.data() + o[g], vertex_weights.data() + o[g + 1]);
             }
             std::vector<double> w(weights.data(), weights.data() + weights.size());
             self.locked([&](D& d) { d.set_handle_groups(groups, w, vw); });
           })
      .def("solve", &solve, py::arg("targets"), py::arg("iterations") = 5, py::arg("out") = py::none(),
           py::arg("tolerance") = 0.0, py::arg("transforms") = false)
      .def("solve_on_device", &solve_on_device, py::arg("targets"), py::arg("iterations") = 5,
           py::arg("tolerance") = 0.0, py::arg("transforms") = false)
      // Poses the lattice and returns its nodes in one locked call: another thread's pose cannot
      // land between the two.
      .def("pose", [](PyDeformer& self, F64 targets, int iterations, double tolerance, bool transforms) {
             const TargetShape shape = shape_of(targets, transforms);
             const double* t = targets.data();
             return to_numpy(self.locked([&](D& d) {
               check_targets(d, shape);
               transforms ? d.pose_transforms(t, iterations, tolerance) : d.pose(t, iterations, tolerance);
               return RowMatrixX3d(d.lattice_deformed());
             }));
           }, py::arg("targets"), py::arg("iterations") = 5, py::arg("tolerance") = 0.0,
           py::arg("transforms") = false)
      .def_property_readonly("num_groups", [](const PyDeformer& self) {
        return self.locked([](const D& d) { return d.num_groups(); });
      })
      .def("reset", [](PyDeformer& self) { self.locked([](D& d) { d.reset(); }); })
      .def_property(
          "weights", [](const PyDeformer& self) {
            return std::string(larap::weight_kind_name(self.locked([](const D& d) { return d.weights(); })));
          },
          [](PyDeformer& self, const std::string& w) {
            const auto k = larap::parse_weight_kind(w);
            self.locked([&](D& d) { d.set_weights(k); });
          })
      .def_property(
          "gamma", [](const PyDeformer& self) { return self.locked([](const D& d) { return d.gamma(); }); },
          [](PyDeformer& self, double g) { self.locked([&](D& d) { d.set_gamma(g); }); })
      .def_property_readonly("num_vertices", [](const PyDeformer& self) { return self.engine.mesh().num_vertices(); })
      .def_property_readonly("num_nodes", [](const PyDeformer& self) { return self.engine.lattice().num_nodes(); })
      .def_property_readonly("num_cells", [](const PyDeformer& self) { return self.engine.lattice().num_cells(); })
      .def_property_readonly("num_components", [](const PyDeformer& self) { return self.engine.lattice().num_components; })
      .def_property_readonly("cell_size", [](const PyDeformer& self) { return self.engine.lattice().h; })
      .def_property_readonly("diagonal", [](const PyDeformer& self) { return self.engine.diagonal(); })
      .def_property_readonly("levels", [](const PyDeformer& self) { return self.engine.levels(); })
      .def_property_readonly("junction_brace", [](const PyDeformer& self) { return self.engine.junction_brace(); })
      .def_property_readonly("device", [](const PyDeformer& self) { return self.engine.device(); })
      .def_property_readonly("fallback_reason", [](const PyDeformer& self) { return self.engine.fallback_reason(); })
      .def_property_readonly("handles", [](const PyDeformer& self) {
        // copied under the lock: another thread's set_handles may replace them meanwhile
        const std::vector<int64_t> h = self.locked([](const D& d) { return d.handles(); });
        return py::array_t<int64_t>(py::ssize_t(h.size()), h.data());
      })
      .def_property_readonly("stats", &stats)
      .def("lattice_rest", [](const PyDeformer& self) { return to_numpy(self.engine.lattice().rest); })
      .def("lattice_deformed", [](const PyDeformer& self) {
        return to_numpy(self.locked([](const D& d) { return d.lattice_deformed(); }));
      })
      .def("lattice_state", [](const PyDeformer& self) {
        const auto state = self.locked([](const D& d) { return d.lattice_state(); });
        py::list out;
        for (const auto& level : state) out.append(to_numpy(level));
        return out;
      })
      .def("set_lattice_state", [](PyDeformer& self, const std::vector<F64>& state) {
        std::vector<RowMatrixX3d> levels;
        for (const F64& a : state) {
          const auto info = a.request();
          require_rows3(info, "every level of a lattice state", -1);
          levels.emplace_back(Eigen::Map<const RowMatrixX3d>(a.data(), info.shape[0], 3));
        }
        self.locked([&](D& d) { d.set_lattice_state(levels); });
      }, py::arg("state"))
      .def("lattice_edges", [](const PyDeformer& self) {
        const auto& e = self.engine.lattice().edges;
        py::array_t<int32_t> a({py::ssize_t(e.size()), py::ssize_t(2)});
        if (!e.empty()) std::memcpy(a.mutable_data(), e.data(), sizeof(int32_t) * 2 * e.size());
        return a;
      })
      .def("lattice_edge_weights", [](const PyDeformer& self) {
        const auto& lat = self.engine.lattice();
        py::array_t<double> a(py::ssize_t(lat.edges.size()));
        for (size_t k = 0; k < lat.edges.size(); ++k) a.mutable_at(k) = lat.edge_weight[k];
        return a;
      })
      .def("junction_braces", [](const PyDeformer& self) {
        const auto b = self.engine.junction_braces();
        py::array_t<int32_t> a({py::ssize_t(b.size()), py::ssize_t(3)});
        if (!b.empty()) std::memcpy(a.mutable_data(), b.data(), sizeof(int32_t) * 3 * b.size());
        return a;
      })
      .def("branch_couplings", [](const PyDeformer& self) {  // (K, 2) branch and trunk copies, (K,) weights
        const auto& c = self.engine.lattice().couplings;
        py::array_t<int32_t> pairs({py::ssize_t(c.size()), py::ssize_t(2)});
        py::array_t<double> w(py::ssize_t(c.size()));
        for (size_t k = 0; k < c.size(); ++k) {
          pairs.mutable_at(k, 0) = c[k].branch;
          pairs.mutable_at(k, 1) = c[k].trunk;
          w.mutable_at(k) = c[k].weight;
        }
        return py::make_tuple(pairs, w);
      })
      .def("cell_weights", [](const PyDeformer& self) {
        const auto& lat = self.engine.lattice();
        py::array_t<double> a(py::ssize_t(lat.num_cells()));
        for (int64_t c = 0; c < lat.num_cells(); ++c)
          a.mutable_at(c) = lat.cell_weight.empty() ? 1.0 : lat.cell_weight[size_t(c)];
        return a;
      })
      .def("cell_kinds", [](const PyDeformer& self) {
        const auto& k = self.engine.lattice().cell_kind;
        return py::array_t<uint8_t>(py::ssize_t(k.size()), k.data());
      })
      .def("cell_coords", [](const PyDeformer& self) {
        const auto& c = self.engine.lattice().cell_coords;
        py::array_t<int32_t> a({py::ssize_t(c.size()), py::ssize_t(3)});
        for (size_t i = 0; i < c.size(); ++i)
          for (int k = 0; k < 3; ++k) a.mutable_at(i, k) = c[i][k];
        return a;
      })
      .def_property_readonly("origin", [](const PyDeformer& self) {
        const auto& o = self.engine.lattice().origin;
        return py::make_tuple(o.x(), o.y(), o.z());
      })
      .def("cell_nodes", [](const PyDeformer& self) {
        const auto& cn = self.engine.lattice().cell_nodes;
        py::array_t<int32_t> a({py::ssize_t(cn.size()), py::ssize_t(8)});
        if (!cn.empty()) std::memcpy(a.mutable_data(), cn.data(), sizeof(int32_t) * 8 * cn.size());
        return a;
      })
      .def("trilinear_binding", [](const PyDeformer& self) {
        // The trilinear binding as arrays: per vertex its cell and its position in the cell.
        // One locked call: the weight kind read and the binding taken for it (bindings, once
        // made, live as long as the Deformer).
        larap::Binding made;
        const larap::Binding* b = self.locked([&](const D& e) -> const larap::Binding* {
          if (e.weights() == larap::WeightKind::Trilinear) return &e.binding();
          made = larap::bind_vertices(e.lattice(), e.mesh().vertices, larap::WeightKind::Trilinear);
          return &made;
        });
        const py::ssize_t n = py::ssize_t(b->base.size());
        py::array_t<int32_t> cells(n);
        py::array_t<float> frac({n, py::ssize_t(3)});
        if (n) {
          std::memcpy(cells.mutable_data(), b->base.data(), sizeof(int32_t) * n);
          std::memcpy(frac.mutable_data(), b->frac.data(), sizeof(float) * 3 * n);
        }
        return py::make_tuple(cells, frac);
      })
      .def("binding_weights", [](const PyDeformer& self, int64_t v) {
        const D& d = self.engine;
        if (v < 0 || v >= d.mesh().num_vertices()) throw larap::InvalidInput("vertex out of range");
        const larap::Binding* b = self.locked([](const D& e) { return &e.binding(); });
        std::vector<int32_t> ids(b->stencil_size());
        std::vector<double> w(b->stencil_size());
        b->weights_of(d.lattice(), v, ids.data(), w.data());
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
  m.attr("MAX_LEVELS") = larap::kMaxLevels;
  m.attr("DEFAULT_GAMMA") = larap::DeformerOptions{}.gamma;  // the one place the default lives
  m.attr("MAX_ITERATIONS") = larap::kMaxIterations;
  m.attr("GAMMA_RANGE") = py::make_tuple(larap::kMinGamma, larap::kMaxGamma);
  m.attr("DEFAULT_JUNCTION_BRACE") = larap::DeformerOptions{}.junction_brace;
  m.attr("MAX_JUNCTION_BRACE") = larap::kMaxJunctionBrace;
}
