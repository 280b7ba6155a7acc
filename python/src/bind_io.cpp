// Mesh file I/O for Python: larap._core.load_mesh / save_mesh in CSR form (vertices, face offsets,
// face indices). The numpy-friendly wrappers with (m, k) face arrays live in python/larap/io.py.
#include <larap/errors.h>
#include <larap/mesh_io.h>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <string>
#include <utility>

namespace py = pybind11;

namespace {

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;
using IndexArray = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

std::string shape_of(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

py::array as_array(const py::object& obj, const char* what) {
  py::array a = py::array::ensure(obj);
  if (!a) throw py::type_error(std::string(what) + " must be array-like");
  return a;
}

// The arrays share one heap-held mesh (no copy); the capsule frees it with the last array.
py::tuple mesh_to_arrays(larap::PolygonMesh&& mesh) {
  auto* held = new larap::PolygonMesh(std::move(mesh));
  py::capsule owner(held, [](void* p) { delete static_cast<larap::PolygonMesh*>(p); });
  const py::ssize_t n = held->vertices.rows();
  py::array_t<double> vertices({n, py::ssize_t(3)}, {py::ssize_t(3 * sizeof(double)), py::ssize_t(sizeof(double))},
                               held->vertices.data(), owner);
  py::array_t<int64_t> offsets(static_cast<py::ssize_t>(held->face_offsets.size()), held->face_offsets.data(), owner);
  py::array_t<int64_t> indices(static_cast<py::ssize_t>(held->face_indices.size()), held->face_indices.data(), owner);
  return py::make_tuple(vertices, offsets, indices);
}

}  // namespace

void bind_io(py::module_& m) {
  m.def(
      "load_mesh",
      [](const std::string& path) {
        larap::PolygonMesh mesh;
        {
          py::gil_scoped_release unlocked;
          mesh = larap::load_mesh(path);
        }
        return mesh_to_arrays(std::move(mesh));
      },
      py::arg("path"),
      "Read an OBJ, PLY or OFF file (format from the extension).\n\n"
      "Returns (vertices, face_offsets, face_indices): #V by 3 float64 positions, #F+1 int64\n"
      "offsets and the concatenated int64 vertex indices of all faces (face f is\n"
      "face_indices[face_offsets[f]:face_offsets[f+1]]). Raises FileNotFoundError, OSError, or\n"
      "ValueError naming the file and line for malformed contents.");

  m.def(
      "save_mesh",
      [](const std::string& path, const py::object& vertices_obj, const py::object& offsets_obj,
         const py::object& indices_obj, bool ascii, const std::string& template_obj) {
        const py::array vertices_in = as_array(vertices_obj, "vertices");
        const py::array offsets_in = as_array(offsets_obj, "face_offsets");
        const py::array indices_in = as_array(indices_obj, "face_indices");
        if (vertices_in.ndim() != 2 || vertices_in.shape(1) != 3)
          throw py::value_error("vertices must have shape (n, 3), got " + shape_of(vertices_in));
        if (offsets_in.ndim() != 1 || offsets_in.shape(0) < 1)
          throw py::value_error("face_offsets must have shape (m + 1,), got " + shape_of(offsets_in));
        if (indices_in.ndim() != 1)
          throw py::value_error("face_indices must have shape (k,), got " + shape_of(indices_in));
        const DoubleArray vertices = DoubleArray::ensure(vertices_in);
        const IndexArray offsets = IndexArray::ensure(offsets_in);
        const IndexArray indices = IndexArray::ensure(indices_in);
        if (!vertices || !offsets || !indices) throw py::error_already_set();
        const int64_t* off = offsets.data();
        const py::ssize_t m_faces = offsets.shape(0) - 1;
        if (off[0] != 0 || off[m_faces] != indices.shape(0))
          throw py::value_error("face_offsets must run from 0 to len(face_indices) = " +
                                std::to_string(indices.shape(0)) + ", got " + std::to_string(off[0]) + " .. " +
                                std::to_string(off[m_faces]));

        larap::PolygonMesh mesh;
        mesh.vertices = Eigen::Map<const larap::RowMatrixX3d>(vertices.data(), vertices.shape(0), 3);
        mesh.face_offsets.assign(off, off + offsets.shape(0));
        mesh.face_indices.assign(indices.data(), indices.data() + indices.shape(0));
        py::gil_scoped_release unlocked;
        larap::save_mesh(path, mesh, ascii, template_obj);
      },
      py::arg("path"), py::arg("vertices"), py::arg("face_offsets"), py::arg("face_indices"),
      py::arg("ascii") = false, py::arg("template_obj") = "",
      "Write a mesh given in CSR form (see load_mesh) to an OBJ, PLY or OFF file, atomically.\n\n"
      "vertices: #V by 3 floats; face_offsets: #F+1 ints; face_indices: ints in [0, #V).\n"
      "PLY is binary little endian unless ascii is true. For OBJ output, template_obj names an\n"
      "OBJ whose lines are copied with only the vertex positions replaced when its vertex count\n"
      "matches (UVs, normals, groups and materials survive); otherwise a plain OBJ is written.");
}
