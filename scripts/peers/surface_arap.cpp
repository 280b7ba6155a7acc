// SPDX-License-Identifier: GPL-3.0-or-later
// Peer program for the evidence report (scripts/evidence): surface ARAP on the full mesh with
// CGAL's Surface_mesh_deformation (Sorkine & Alexa 2007, CGAL's ORIGINAL_ARAP), from Debian's
// libcgal-dev. Built only by scripts/peers/surface_arap.py into a build folder; never linked into
// the product.
//
//   surface_arap MESH.bin POSES.bin OUT.bin ITERATIONS TOLERANCE
//
// MESH.bin (little-endian): int64 n, int64 m, n*3 float64 positions, m*3 int64 triangles,
//   int64 r, r int64 region-of-interest vertex ids, int64 c, c int64 control (handle) vertex ids.
// POSES.bin: int64 p, then p times c*3 float64 targets (the control vertices' positions).
// OUT.bin: p times n*3 float64 deformed positions, each pose warm-started from the one before.
// stdout: one JSON object: faces skipped by the halfedge mesh, milliseconds of the
// preprocessing (factorisation) and of each pose's deform(), and CGAL's iteration limit.
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_deformation.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using Vertex = Mesh::Vertex_index;
using Deformation = CGAL::Surface_mesh_deformation<Mesh>;

namespace {

struct Reader {
  std::ifstream in;
  explicit Reader(const std::string& path) : in(path, std::ios::binary) {
    if (!in) throw std::runtime_error("cannot open " + path);
  }
  template <class T>
  std::vector<T> read(std::int64_t count) {
    if (count < 0) throw std::runtime_error("negative count in input");
    std::vector<T> v(static_cast<std::size_t>(count));
    in.read(reinterpret_cast<char*>(v.data()), static_cast<std::streamsize>(count * sizeof(T)));
    if (!in) throw std::runtime_error("input ends early");
    return v;
  }
  std::int64_t count() { return read<std::int64_t>(1)[0]; }
};

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::cerr << "usage: surface_arap MESH.bin POSES.bin OUT.bin ITERATIONS TOLERANCE\n";
    return 2;
  }
  try {
    Reader mesh_in(argv[1]);
    const std::int64_t n = mesh_in.count(), m = mesh_in.count();
    const auto xyz = mesh_in.read<double>(3 * n);
    const auto tris = mesh_in.read<std::int64_t>(3 * m);
    const auto roi = mesh_in.read<std::int64_t>(mesh_in.count());
    const auto controls = mesh_in.read<std::int64_t>(mesh_in.count());
    const unsigned iterations = static_cast<unsigned>(std::stoul(argv[4]));
    const double tolerance = std::stod(argv[5]);

    Mesh mesh;
    std::vector<Vertex> vid(static_cast<std::size_t>(n));
    for (std::int64_t i = 0; i < n; ++i) vid[i] = mesh.add_vertex(Point(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]));
    std::int64_t skipped = 0;
    for (std::int64_t f = 0; f < m; ++f) {
      const std::int64_t a = tris[3 * f], b = tris[3 * f + 1], c = tris[3 * f + 2];
      if (a < 0 || b < 0 || c < 0 || a >= n || b >= n || c >= n) throw std::runtime_error("face index out of range");
      if (mesh.add_face(vid[a], vid[b], vid[c]) == Mesh::null_face()) ++skipped;  // non-manifold: CGAL refuses it
    }

    auto t0 = std::chrono::steady_clock::now();
    Deformation deform(mesh);
    for (auto i : roi) deform.insert_roi_vertex(vid.at(static_cast<std::size_t>(i)));
    for (auto i : controls) deform.insert_control_vertex(vid.at(static_cast<std::size_t>(i)));
    const bool ok = deform.preprocess();
    const double preprocess_ms = ms_since(t0);
    if (!ok) {
      std::printf("{\"ok\": false, \"error\": \"preprocess failed (singular system)\", \"skipped_faces\": %lld, "
                  "\"preprocess_ms\": %.3f}\n", static_cast<long long>(skipped), preprocess_ms);
      return 3;
    }

    Reader poses_in(argv[2]);
    const std::int64_t p = poses_in.count();
    std::ofstream out(argv[3], std::ios::binary);
    std::string pose_ms;
    std::vector<double> X(static_cast<std::size_t>(3 * n));
    for (std::int64_t k = 0; k < p; ++k) {
      const auto targets = poses_in.read<double>(3 * static_cast<std::int64_t>(controls.size()));
      for (std::size_t j = 0; j < controls.size(); ++j)
        deform.set_target_position(vid[static_cast<std::size_t>(controls[j])],
                                   Point(targets[3 * j], targets[3 * j + 1], targets[3 * j + 2]));
      t0 = std::chrono::steady_clock::now();
      deform.deform(iterations, tolerance);
      const double ms = ms_since(t0);
      pose_ms += (k ? ", " : "") + std::to_string(ms);
      for (std::int64_t i = 0; i < n; ++i) {
        const Point& q = mesh.point(vid[static_cast<std::size_t>(i)]);
        X[3 * i] = q.x(), X[3 * i + 1] = q.y(), X[3 * i + 2] = q.z();
      }
      out.write(reinterpret_cast<const char*>(X.data()), static_cast<std::streamsize>(X.size() * sizeof(double)));
    }
    if (!out) throw std::runtime_error(std::string("cannot write ") + argv[3]);
    std::printf("{\"ok\": true, \"skipped_faces\": %lld, \"preprocess_ms\": %.3f, \"pose_ms\": [%s], "
                "\"iterations\": %u, \"tolerance\": %g}\n",
                static_cast<long long>(skipped), preprocess_ms, pose_ms.c_str(), iterations, tolerance);
    return 0;
  } catch (const std::exception& e) {
    std::printf("{\"ok\": false, \"error\": \"%s\"}\n", e.what());
    return 1;
  }
}
