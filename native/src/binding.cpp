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

Binding bind_vertices(const Lattice& lat, const RowMatrixX3d& V, WeightKind kind) {
  Binding b;
  b.kind = kind;
  const int64_t n = V.rows();
  b.base.resize(static_cast<size_t>(n));
  b.frac.resize(static_cast<size_t>(3 * n));
  std::atomic<bool> missing{false};
  if (kind == WeightKind::Trilinear) {
    parallel_for(n, [&](int64_t v) {
      int c[3];
      for (int a = 0; a < 3; ++a) {
        const double local = (V(v, a) - lat.origin[a]) / lat.h;
        const double f = std::floor(local);
        c[a] = static_cast<int>(std::clamp(f, 0.0, double(lat.dims[a] - 1)));
        b.frac[3 * v + a] = static_cast<float>(std::clamp(local - c[a], 0.0, 1.0));
      }
      b.base[v] = lat.cell_at(c[0], c[1], c[2]);
      if (b.base[v] < 0) missing = true;
    }, 4096);
  } else {
    const int64_t nn = lat.num_nodes();
    b.node27.assign(static_cast<size_t>(27 * nn), -1);
    parallel_for(nn, [&](int64_t i) {
      const Eigen::Vector3i& p = lat.node_coords[i];
      int k = 0;
      for (int z = -1; z <= 1; ++z)
        for (int y = -1; y <= 1; ++y)
          for (int x = -1; x <= 1; ++x, ++k) b.node27[27 * i + k] = lat.node_at(p.x() + x, p.y() + y, p.z() + z);
    });
    parallel_for(n, [&](int64_t v) {
      int c[3];
      for (int a = 0; a < 3; ++a) {
        const double local = (V(v, a) - lat.origin[a]) / lat.h;
        const double r = std::floor(local + 0.5);
        c[a] = static_cast<int>(std::clamp(r, 1.0, double(lat.dims[a] - 1)));
        b.frac[3 * v + a] = static_cast<float>(std::clamp(local - c[a], -0.5, 0.5));
      }
      const int32_t id = lat.node_at(c[0], c[1], c[2]);
      b.base[v] = id;
      bool complete = id >= 0;
      for (int k = 0; complete && k < 27; ++k) complete = b.node27[27 * int64_t(id) + k] >= 0;
      if (!complete) missing = true;
    }, 4096);
  }
  if (missing)
    throw InvalidInput("internal: a vertex lies outside the lattice it was built for (was the "
                       "lattice built from other vertices?)");
  return b;
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
