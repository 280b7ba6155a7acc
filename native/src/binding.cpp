#include <larap/binding.h>
#include <larap/errors.h>

#include <atomic>
#include <cmath>

#include "parallel.h"
#include "stencil.h"

namespace larap {

WeightKind parse_weight_kind(const std::string& name) {
  if (name == "trilinear") return WeightKind::Trilinear;
  if (name == "bspline") return WeightKind::BSpline;
  throw InvalidInput("weights must be 'trilinear' or 'bspline', got '" + name + "'");
}

const char* weight_kind_name(WeightKind kind) {
  return kind == WeightKind::Trilinear ? "trilinear" : "bspline";
}

namespace {

template <typename T>
void transfer_impl(const Lattice& lat, const Binding& b, const RowMatrixX3d& V,
                   const RowMatrixX3d& D, T* out) {
  const int64_t n = b.num_vertices();
  const double* d = D.data();
  if (b.kind == WeightKind::Trilinear) {
    parallel_for(n, [&](int64_t v) {
      const auto& ids = lat.cell_nodes[b.base[v]];
      double w[8];
      trilinear_weights<double>(b.frac[3 * v], b.frac[3 * v + 1], b.frac[3 * v + 2], w);
      double acc[3] = {0.0, 0.0, 0.0};
      for (int c = 0; c < 8; ++c) {
        const double* p = d + 3 * int64_t(ids[c]);
        acc[0] += w[c] * p[0];
        acc[1] += w[c] * p[1];
        acc[2] += w[c] * p[2];
      }
      for (int k = 0; k < 3; ++k) out[3 * v + k] = static_cast<T>(V(v, k) + acc[k]);
    }, 2048);
  } else {
    parallel_for(n, [&](int64_t v) {
      const int32_t* ids = b.node27.data() + 27 * int64_t(b.base[v]);
      double w[27];
      bspline_weights<double>(b.frac[3 * v], b.frac[3 * v + 1], b.frac[3 * v + 2], w);
      double acc[3] = {0.0, 0.0, 0.0};
      for (int k = 0; k < 27; ++k) {
        const double* p = d + 3 * int64_t(ids[k]);
        acc[0] += w[k] * p[0];
        acc[1] += w[k] * p[1];
        acc[2] += w[k] * p[2];
      }
      for (int c = 0; c < 3; ++c) out[3 * v + c] = static_cast<T>(V(v, c) + acc[c]);
    }, 1024);
  }
}

}  // namespace

void Binding::weights_of(const Lattice& lat, int64_t v, int32_t* ids, double* w) const {
  if (kind == WeightKind::Trilinear) {
    const auto& cn = lat.cell_nodes[base[v]];
    double wt[8];
    trilinear_weights<double>(frac[3 * v], frac[3 * v + 1], frac[3 * v + 2], wt);
    for (int c = 0; c < 8; ++c) {
      ids[c] = cn[c];
      w[c] = wt[c];
    }
  } else {
    double wb[27];
    bspline_weights<double>(frac[3 * v], frac[3 * v + 1], frac[3 * v + 2], wb);
    for (int k = 0; k < 27; ++k) {
      ids[k] = node27[27 * int64_t(base[v]) + k];
      w[k] = wb[k];
    }
  }
}

Binding bind_points(const Lattice& lat, const RowMatrixX3d& V, const std::vector<int32_t>& cells,
                    WeightKind kind) {
  Binding b;
  b.kind = kind;
  const int64_t n = V.rows();
  if (int64_t(cells.size()) != n)
    throw InvalidInput("internal: " + std::to_string(cells.size()) + " cells for " + std::to_string(n) + " points");
  if (kind == WeightKind::BSpline && lat.stencil27.empty())
    throw InvalidInput("internal: this lattice has no B-spline stencils");
  b.base.resize(static_cast<size_t>(n));
  b.frac.resize(static_cast<size_t>(3 * n));
  std::atomic<bool> missing{false};
  parallel_for(n, [&](int64_t v) {
    const int32_t c = cells[v];
    if (c < 0 || c >= lat.num_cells()) {
      missing = true;
      return;
    }
    const Eigen::Vector3i& cc = lat.cell_coords[c];
    int corner = 0;
    for (int a = 0; a < 3; ++a) {
      const double f = std::clamp((V(v, a) - lat.origin[a]) / lat.h - cc[a], 0.0, 1.0);
      if (kind == WeightKind::Trilinear) {
        b.frac[3 * v + a] = static_cast<float>(f);
      } else {  // offset from the nearest corner of the cell, in [-1/2, 1/2]
        const int up = f >= 0.5 ? 1 : 0;
        corner |= up << a;
        b.frac[3 * v + a] = static_cast<float>(f - up);
      }
    }
    b.base[v] = kind == WeightKind::Trilinear ? c : lat.cell_nodes[c][corner];
  }, 4096);
  if (missing)
    throw InvalidInput("internal: a point lies outside the lattice it was built for (was the "
                       "lattice built from other vertices?)");
  if (kind == WeightKind::BSpline) b.node27 = lat.stencil27;
  return b;
}

Binding bind_vertices(const Lattice& lat, const RowMatrixX3d& V, WeightKind kind) {
  if (int64_t(lat.vertex_cell.size()) != V.rows())
    throw InvalidInput("internal: the lattice was built for " + std::to_string(lat.vertex_cell.size()) +
                       " vertices, not " + std::to_string(V.rows()));
  return bind_points(lat, V, lat.vertex_cell, kind);
}

void transfer(const Lattice& lattice, const Binding& binding, const RowMatrixX3d& vertices,
              const RowMatrixX3d& displacement, double* out) {
  transfer_impl(lattice, binding, vertices, displacement, out);
}
void transfer(const Lattice& lattice, const Binding& binding, const RowMatrixX3d& vertices,
              const RowMatrixX3d& displacement, float* out) {
  transfer_impl(lattice, binding, vertices, displacement, out);
}

}  // namespace larap
