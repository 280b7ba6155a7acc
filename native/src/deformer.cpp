// larap::Deformer: owns the mesh, the lattice, the bindings, the fine level's backend and the
// coarse levels (hierarchy.h); a solve is a sequence of named steps (pose_lattice).
#include <larap/deformer.h>
#include <larap/errors.h>

#include <chrono>
#include <cmath>
#include <unordered_set>

#include "backend.h"
#include "energy.h"
#include "handle_system.h"
#include "hierarchy.h"

namespace larap {
namespace {

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

std::unique_ptr<Backend> make_backend(const std::string& device, const Lattice& lat,
                                      const RowMatrixX3d& V, std::string& fallback) {
  if (device == "cpu") return make_cpu_backend(lat, V);
  if (device == "cuda") {
    std::string why;
    if (!cuda_available(&why)) throw DeviceError("device 'cuda' is not available: " + why);
    return make_cuda_backend(lat, V);
  }
  if (device == "auto") {
    if (cuda_available(nullptr)) {
      try {
        return make_cuda_backend(lat, V);
      } catch (const OutOfMemory& e) {  // falls back to the CPU; device() says which one runs
        fallback = std::string("device 'auto' fell back to the CPU: ") + e.what();
      } catch (const DeviceError& e) {
        fallback = std::string("device 'auto' fell back to the CPU: ") + e.what();
      }
    }
    return make_cpu_backend(lat, V);
  }
  throw InvalidInput("device must be 'cpu', 'cuda' or 'auto', got '" + device + "'");
}

void check_gamma(double gamma) {
  if (!(gamma > 0.0) || !std::isfinite(gamma))
    throw InvalidInput("gamma must be a positive finite number, got " + std::to_string(gamma));
}

void check_levels(int levels) {
  if (levels < 1 || levels > kMaxLevels)
    throw InvalidInput("levels must be between 1 and " + std::to_string(kMaxLevels) + ", got " +
                       std::to_string(levels));
}

}  // namespace

// ------------------------------------------------------------------------------------ state
struct Deformer::Impl {
  PolygonMesh mesh;
  Lattice lattice;
  WeightKind weights;
  double gamma;
  double diagonal = 1.0;  // bounding-box diagonal of the rest mesh
  double size = 1.0;      // radius of gyration of the rest vertices (the gamma's length scale)
  mutable std::unique_ptr<Binding> bindings[2];  // per weight kind, made on first use
  std::unique_ptr<Backend> backend;              // the fine level
  Hierarchy hierarchy;                           // the coarse levels
  std::vector<int64_t> handles;
  RowMatrixX3d rest_handles;  // rest positions of the handles
  std::vector<uint8_t> fine_anchored;
  bool handles_set = false;
  bool auto_device = false;
  std::string fallback;
  SolveStats stats;

  const Binding& binding() const {
    auto& slot = bindings[weights == WeightKind::Trilinear ? 0 : 1];
    if (!slot) slot = std::make_unique<Binding>(bind_vertices(lattice, mesh.vertices, weights));
    return *slot;
  }

  void prepare_handles();
  void replace_backend_with_cpu(const HandleSystem& hs, const OutOfMemory& why);
  bool pose_lattice(const double* targets, int iterations, double tolerance);
  void check_solve_args(const double* targets, int iterations, double tolerance) const;
  void choose_start(const RowMatrixX3d& targets);
  void coarse_to_fine(const RowMatrixX3d& targets, int iterations);
  void iterate_fine(const RowMatrixX3d& targets, int iterations, double tolerance);
  template <typename T>
  void solve(const double* targets, int iterations, T* out, double tolerance);
};

// ------------------------------------------------------------------------------------ construction
Deformer::Deformer(PolygonMesh mesh, const DeformerOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  check_gamma(options.gamma);
  check_levels(options.levels);
  d.mesh = std::move(mesh);
  d.weights = options.weights;
  d.gamma = options.gamma;
  validate_mesh(d.mesh);
  auto t0 = Clock::now();
  d.lattice = Lattice::build(d.mesh, options.lattice);
  d.stats.ms_lattice = ms_since(t0);
  const RowMatrixX3d& V = d.mesh.vertices;
  const Eigen::Vector3d ext = (V.colwise().maxCoeff() - V.colwise().minCoeff()).transpose();
  d.diagonal = ext.norm() > 0.0 ? ext.norm() : d.lattice.h;
  const Eigen::RowVector3d centroid = V.colwise().mean();
  d.size = std::sqrt((V.rowwise() - centroid).rowwise().squaredNorm().mean());
  if (!(d.size > 0.0)) d.size = d.lattice.h;
  t0 = Clock::now();
  d.binding();
  d.stats.ms_binding = ms_since(t0);
  d.backend = make_backend(options.device, d.lattice, V, d.fallback);
  d.auto_device = options.device == "auto";
  d.hierarchy = Hierarchy(d.lattice, V, options.levels);
}

Deformer::~Deformer() = default;

// ------------------------------------------------------------------------------------ handles
void Deformer::set_handles(const std::vector<int64_t>& indices) {
  Impl& d = *impl_;
  const int64_t n = d.mesh.num_vertices();
  std::unordered_set<int64_t> seen;
  seen.reserve(indices.size() * 2);
  for (size_t k = 0; k < indices.size(); ++k) {
    const int64_t v = indices[k];
    if (v < 0 || v >= n)
      throw InvalidInput("handle " + std::to_string(k) + " is vertex " + std::to_string(v) +
                         ", out of range for " + std::to_string(n) + " vertices");
    if (!seen.insert(v).second)
      throw InvalidInput("vertex " + std::to_string(v) + " is given twice as a handle (at " +
                         std::to_string(k) + ")");
  }
  d.handles = indices;
  d.handles_set = true;
  d.rest_handles.resize(int64_t(indices.size()), 3);
  for (size_t j = 0; j < indices.size(); ++j) d.rest_handles.row(j) = d.mesh.vertices.row(indices[j]);
  d.prepare_handles();
}

void Deformer::set_weights(WeightKind kind) {
  Impl& d = *impl_;
  if (kind == d.weights) return;
  d.weights = kind;
  if (d.handles_set) d.prepare_handles();
}

void Deformer::set_gamma(double gamma) {
  Impl& d = *impl_;
  check_gamma(gamma);
  d.gamma = gamma;
  if (d.handles_set) d.prepare_handles();
}

void Deformer::reset() {
  impl_->backend->set_pose(impl_->lattice.rest);
  impl_->hierarchy.reset();
}

void Deformer::Impl::prepare_handles() {
  const auto t0 = Clock::now();
  const Binding& b = binding();
  const int s = b.stencil_size();
  const int64_t mh = static_cast<int64_t>(handles.size());
  std::vector<int32_t> ids(size_t(mh) * s);
  std::vector<double> w(ids.size());
  for (int64_t j = 0; j < mh; ++j) b.weights_of(lattice, handles[j], &ids[j * s], &w[j * s]);
  HandleSystem hs = make_handle_system(lattice, s, std::move(ids), std::move(w), gamma, size);
  fine_anchored = hs.anchored;
  hierarchy.set_handles(rest_handles, gamma, size);
  if (hs.m > 0) {
    try {
      backend->set_handles(hs);
    } catch (const OutOfMemory& e) {
      if (!auto_device || backend->name() == "cpu") throw;
      replace_backend_with_cpu(hs, e);
    }
  }
  stats.ms_factorize = ms_since(t0);
}

// device="auto": a GPU too small for this handle set hands over to the CPU, pose kept.
void Deformer::Impl::replace_backend_with_cpu(const HandleSystem& hs, const OutOfMemory& why) {
  RowMatrixX3d pose;
  backend->get_pose(pose);
  backend.reset();  // free the device memory first
  backend = make_cpu_backend(lattice, mesh.vertices);
  backend->set_pose(pose);
  backend->set_handles(hs);
  fallback = std::string("device 'auto' fell back to the CPU: ") + why.what();
}

// ------------------------------------------------------------------------------------ posing
void Deformer::solve(const double* targets, int iterations, double* out, double tolerance) {
  impl_->solve(targets, iterations, out, tolerance);
}
void Deformer::solve(const double* targets, int iterations, float* out, double tolerance) {
  impl_->solve(targets, iterations, out, tolerance);
}

void Deformer::pose(const double* targets, int iterations, double tolerance) {
  impl_->pose_lattice(targets, iterations, tolerance);  // no handles: the lattice stays at rest
}

const float* Deformer::solve_on_device(const double* targets, int iterations, double tolerance) {
  Impl& d = *impl_;
  if (d.backend->name() == "cpu")
    throw DeviceError("solve_on_device needs the CUDA backend; this Deformer runs on the CPU");
  const auto t0 = Clock::now();
  d.pose_lattice(targets, iterations, tolerance);  // no handles: the lattice stays at rest
  const float* p = d.backend->transfer_on_device(d.binding(), d.stats);
  if (!p) throw DeviceError("this backend cannot leave the positions on the device");
  d.stats.ms_total = ms_since(t0);
  return p;
}

template <typename T>
void Deformer::Impl::solve(const double* targets, int iterations, T* out, double tolerance) {
  const auto t0 = Clock::now();
  if (!pose_lattice(targets, iterations, tolerance)) {  // no handles: the rest pose
    const int64_t n = mesh.num_vertices();
    for (int64_t i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) out[3 * i + c] = static_cast<T>(mesh.vertices(i, c));
  } else {
    backend->transfer(binding(), out, stats);
  }
  stats.ms_total = ms_since(t0);
}

// The lattice pose for `targets`: checks, start, coarse levels, fine iterations. False when
// there are no handles (the lattice stays at rest).
bool Deformer::Impl::pose_lattice(const double* targets, int iterations, double tolerance) {
  check_solve_args(targets, iterations, tolerance);
  const auto t0 = Clock::now();
  stats.clear_solve();
  const int64_t m = static_cast<int64_t>(handles.size());
  if (m == 0) return false;
  const RowMatrixX3d tgt = Eigen::Map<const RowMatrixX3d>(targets, m, 3);
  choose_start(tgt);
  stats.ms_start = ms_since(t0);
  coarse_to_fine(tgt, iterations);
  iterate_fine(tgt, iterations, tolerance);
  stats.ms_total = ms_since(t0);
  return true;
}

void Deformer::Impl::check_solve_args(const double* targets, int iterations, double tolerance) const {
  if (!handles_set) throw StateError("solve() needs set_handles() first");
  if (iterations < 0 || iterations > kMaxIterations)
    throw InvalidInput("iterations must be between 0 and " + std::to_string(kMaxIterations) +
                       ", got " + std::to_string(iterations));
  if (!(tolerance >= 0.0) || !std::isfinite(tolerance))
    throw InvalidInput("tolerance must be a non-negative number, got " + std::to_string(tolerance));
  const int64_t m = static_cast<int64_t>(handles.size());
  for (int64_t k = 0; k < 3 * m; ++k)
    if (!std::isfinite(targets[k]))
      throw InvalidInput("targets[" + std::to_string(k / 3) + "] has a non-finite coordinate");
}

// Smarter start for large moves: carry the previous pose by the best rigid motion of the
// handles when that explains most of the move; and when the targets are close to a rigid
// motion of the handles' rest positions, also try the rigidly moved rest pose.
void Deformer::Impl::choose_start(const RowMatrixX3d& tgt) {
  RowMatrixX3d current;
  backend->handle_positions(current);
  const double before = (current - tgt).squaredNorm();
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  const double carried = rigid_fit(current, tgt, R, t);
  if (carried < 0.5 * before) {
    backend->apply_rigid(R, t);
    hierarchy.apply_rigid(R, t);
    stats.rigid_carry = true;
  }
  Eigen::Matrix3d R0;
  Eigen::Vector3d t0;
  const double from_rest = rigid_fit(rest_handles, tgt, R0, t0);
  if (from_rest < std::min(before, carried)) {
    const double e_prev = backend->energy(tgt);
    RowMatrixX3d prev;
    backend->get_pose(prev);
    backend->set_pose(lattice.rest);
    backend->apply_rigid(R0, t0);
    const double e_rest = backend->energy(tgt);
    if (!(e_rest < e_prev))
      backend->set_pose(prev);
    else
      hierarchy.restart_rigid(R0, t0);
  }
}

// Coarse to fine: the coarse levels' increment is added to the fine level's previous pose, so
// fine detail of the previous pose is kept and large-scale motion arrives at once.
void Deformer::Impl::coarse_to_fine(const RowMatrixX3d& tgt, int iterations) {
  if (hierarchy.size() == 0) return;
  const auto t0 = Clock::now();
  const RowMatrixX3d increment = hierarchy.solve_increment(tgt, iterations, fine_anchored);
  RowMatrixX3d fine;
  backend->get_pose(fine);
  backend->set_pose(fine + increment);
  stats.ms_coarse = ms_since(t0);
}

void Deformer::Impl::iterate_fine(const RowMatrixX3d& tgt, int iterations, double tolerance) {
  if (tolerance <= 0.0) {
    backend->iterate(tgt, iterations, stats);
    stats.iterations = iterations;
    return;
  }
  // In chunks, so that a backend keeps its fused multi-iteration path.
  int done = 0;
  while (done < iterations) {
    const int chunk = std::min(5, iterations - done);
    backend->iterate(tgt, chunk, stats);
    done += chunk;
    const auto& e = stats.energy;
    const size_t k = e.size();
    if (k >= 2 && e[k - 2] - e[k - 1] <= tolerance * e[k - 1]) break;
    if (k >= 1 && e[k - 1] == 0.0) break;
  }
  stats.iterations = done;
}

// ------------------------------------------------------------------------------------ inspection
const Lattice& Deformer::lattice() const { return impl_->lattice; }
const PolygonMesh& Deformer::mesh() const { return impl_->mesh; }
const Binding& Deformer::binding() const { return impl_->binding(); }
RowMatrixX3d Deformer::lattice_deformed() const {
  RowMatrixX3d p;
  impl_->backend->get_pose(p);
  return p;
}
const std::vector<int64_t>& Deformer::handles() const { return impl_->handles; }
WeightKind Deformer::weights() const { return impl_->weights; }
double Deformer::gamma() const { return impl_->gamma; }
double Deformer::diagonal() const { return impl_->diagonal; }
std::string Deformer::device() const { return impl_->backend->name(); }
const std::string& Deformer::fallback_reason() const { return impl_->fallback; }
int Deformer::levels() const { return 1 + impl_->hierarchy.size(); }
const SolveStats& Deformer::stats() const { return impl_->stats; }

std::vector<std::string> available_devices() {
  std::vector<std::string> d{"cpu"};
  if (cuda_available(nullptr)) d.push_back("cuda");
  return d;
}

}  // namespace larap
