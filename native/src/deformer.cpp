#include <larap/deformer.h>
#include <larap/errors.h>

#include <chrono>
#include <cmath>
#include <unordered_set>

#include "backend.h"
#include "energy.h"

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

}  // namespace

Deformer::Deformer(PolygonMesh mesh, const DeformerOptions& options)
    : mesh_(std::move(mesh)), weights_(options.weights), gamma_(options.gamma) {
  check_gamma(gamma_);
  validate_mesh(mesh_);
  auto t0 = Clock::now();
  lattice_ = Lattice::build(mesh_, options.lattice);
  stats_.ms_lattice = ms_since(t0);
  const Eigen::Vector3d ext =
      (mesh_.vertices.colwise().maxCoeff() - mesh_.vertices.colwise().minCoeff()).transpose();
  diagonal_ = ext.norm() > 0.0 ? ext.norm() : lattice_.h;
  const Eigen::RowVector3d centroid = mesh_.vertices.colwise().mean();
  size_ = std::sqrt((mesh_.vertices.rowwise() - centroid).rowwise().squaredNorm().mean());
  if (!(size_ > 0.0)) size_ = lattice_.h;
  t0 = Clock::now();
  binding();
  stats_.ms_binding = ms_since(t0);
  backend_ = make_backend(options.device, lattice_, mesh_.vertices, fallback_);
  auto_device_ = options.device == "auto";
}

Deformer::~Deformer() = default;

const Binding& Deformer::binding() const {
  auto& slot = bindings_[weights_ == WeightKind::Trilinear ? 0 : 1];
  if (!slot) slot = std::make_unique<Binding>(bind_vertices(lattice_, mesh_.vertices, weights_));
  return *slot;
}

std::string Deformer::device() const { return backend_->name(); }

void Deformer::set_handles(const std::vector<int64_t>& indices) {
  const int64_t n = mesh_.num_vertices();
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
  handles_ = indices;
  handles_set_ = true;
  rest_handles_.resize(int64_t(indices.size()), 3);
  for (size_t j = 0; j < indices.size(); ++j) rest_handles_.row(j) = mesh_.vertices.row(indices[j]);
  prepare_handles();
}

void Deformer::set_weights(WeightKind kind) {
  if (kind == weights_) return;
  weights_ = kind;
  if (handles_set_) prepare_handles();
}

void Deformer::set_gamma(double gamma) {
  check_gamma(gamma);
  gamma_ = gamma;
  if (handles_set_) prepare_handles();
}

void Deformer::reset() { backend_->set_pose(lattice_.rest); }

RowMatrixX3d Deformer::lattice_deformed() const {
  RowMatrixX3d p;
  backend_->get_pose(p);
  return p;
}

void Deformer::prepare_handles() {
  const auto t0 = Clock::now();
  const Binding& b = binding();
  HandleSystem hs;
  hs.m = static_cast<int64_t>(handles_.size());
  hs.stencil = b.stencil_size();
  hs.ids.resize(size_t(hs.m) * hs.stencil);
  hs.weights.resize(size_t(hs.m) * hs.stencil);
  for (int64_t j = 0; j < hs.m; ++j)
    b.weights_of(lattice_, handles_[j], &hs.ids[j * hs.stencil], &hs.weights[j * hs.stencil]);

  // Scale-free gamma: E = gamma * s^2 * mean_e(|r_e|^2 / h^2) + mean_j |B_j c' - t_j|^2, with s
  // the radius of gyration of the rest vertices. Multiplying by m gives the paper's form with
  // gamma_eff = gamma * m * s^2 / (h^2 * #directed edges). A uniform strain eps of the whole
  // lattice costs as much as every handle missing its target by sqrt(gamma) * eps * s.
  const double m = std::max<int64_t>(hs.m, 1);
  const double directed = std::max<double>(1.0, 2.0 * double(lattice_.edges.size()));
  const double s = size_, h = lattice_.h;
  hs.gamma_eff = gamma_ * m * s * s / (h * h * directed);
  hs.energy_scale = 1.0 / (m * s * s);

  // Components without a handle stay at rest (their system would be singular otherwise).
  std::vector<uint8_t> has_handle(size_t(lattice_.num_components), 0);
  for (int64_t j = 0; j < hs.m; ++j)
    for (int k = 0; k < hs.stencil; ++k)
      if (hs.weights[j * hs.stencil + k] != 0.0)
        has_handle[lattice_.component[hs.ids[j * hs.stencil + k]]] = 1;
  const int64_t nn = lattice_.num_nodes();
  hs.anchored.resize(size_t(nn));
  for (int64_t i = 0; i < nn; ++i) hs.anchored[i] = has_handle[lattice_.component[i]] ? 0 : 1;
  hs.anchor_weight = 2.0 * hs.gamma_eff;

  if (hs.m > 0) {
    try {
      backend_->set_handles(hs);
    } catch (const OutOfMemory& e) {
      // device="auto": a GPU too small for this handle set hands over to the CPU, pose kept.
      if (!auto_device_ || backend_->name() == "cpu") throw;
      RowMatrixX3d pose;
      backend_->get_pose(pose);
      backend_.reset();  // free the device memory first
      backend_ = make_cpu_backend(lattice_, mesh_.vertices);
      backend_->set_pose(pose);
      backend_->set_handles(hs);
      fallback_ = std::string("device 'auto' fell back to the CPU: ") + e.what();
    }
  }
  stats_.ms_factorize = ms_since(t0);
}

void Deformer::solve(const double* targets, int iterations, double* out, double tolerance) {
  solve_impl(targets, iterations, out, tolerance);
}
void Deformer::solve(const double* targets, int iterations, float* out, double tolerance) {
  solve_impl(targets, iterations, out, tolerance);
}

bool Deformer::pose_lattice(const double* targets, int iterations, double tolerance) {
  if (!handles_set_) throw StateError("solve() needs set_handles() first");
  if (iterations < 0 || iterations > 100000)
    throw InvalidInput("iterations must be between 0 and 100000, got " + std::to_string(iterations));
  if (!(tolerance >= 0.0) || !std::isfinite(tolerance))
    throw InvalidInput("tolerance must be a non-negative number, got " + std::to_string(tolerance));
  const int64_t m = static_cast<int64_t>(handles_.size());
  for (int64_t k = 0; k < 3 * m; ++k)
    if (!std::isfinite(targets[k]))
      throw InvalidInput("target " + std::to_string(k / 3) + " has a non-finite coordinate");
  const auto t0 = Clock::now();
  stats_.clear_solve();
  if (m == 0) return false;
  const Eigen::Map<const RowMatrixX3d> T3(targets, m, 3);
  const RowMatrixX3d tgt = T3;

  // Smarter start for large moves: carry the previous pose by the best rigid motion of the
  // handles when that explains most of the move; and when the targets are close to a rigid
  // motion of the handles' rest positions, also try the rigidly moved rest pose.
  RowMatrixX3d current;
  backend_->handle_positions(current);
  const double before = (current - tgt).squaredNorm();
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  const double carried = rigid_fit(current, tgt, R, t);
  if (carried < 0.5 * before) {
    backend_->apply_rigid(R, t);
    stats_.rigid_carry = true;
  }
  Eigen::Matrix3d R0;
  Eigen::Vector3d t0r;
  const double from_rest = rigid_fit(rest_handles_, tgt, R0, t0r);
  if (from_rest < std::min(before, carried)) {
    const double e_prev = backend_->energy(tgt);
    RowMatrixX3d prev;
    backend_->get_pose(prev);
    backend_->set_pose(lattice_.rest);
    backend_->apply_rigid(R0, t0r);
    const double e_rest = backend_->energy(tgt);
    if (!(e_rest < e_prev)) backend_->set_pose(prev);
  }

  stats_.ms_start = ms_since(t0);
  if (tolerance > 0.0) {
    // In chunks, so that a backend keeps its fused multi-iteration path.
    int done = 0;
    while (done < iterations) {
      const int chunk = std::min(5, iterations - done);
      backend_->iterate(tgt, chunk, stats_);
      done += chunk;
      const auto& e = stats_.energy;
      const size_t k = e.size();
      if (k >= 2 && e[k - 2] - e[k - 1] <= tolerance * e[k - 1]) break;
      if (k >= 1 && e[k - 1] == 0.0) break;
    }
    stats_.iterations = done;
  } else {
    backend_->iterate(tgt, iterations, stats_);
    stats_.iterations = iterations;
  }
  stats_.ms_total = ms_since(t0);
  return true;
}

template <typename T>
void Deformer::solve_impl(const double* targets, int iterations, T* out, double tolerance) {
  const auto t0 = Clock::now();
  if (!pose_lattice(targets, iterations, tolerance)) {  // no handles: the rest pose
    const int64_t n = mesh_.num_vertices();
    for (int64_t i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) out[3 * i + c] = static_cast<T>(mesh_.vertices(i, c));
  } else {
    backend_->transfer(binding(), out, stats_);
  }
  stats_.ms_total = ms_since(t0);
}

const float* Deformer::solve_on_device(const double* targets, int iterations, double tolerance) {
  if (backend_->name() == "cpu")
    throw DeviceError("solve_on_device needs the CUDA backend; this Deformer runs on the CPU");
  const auto t0 = Clock::now();
  pose_lattice(targets, iterations, tolerance);  // no handles: the lattice stays at rest
  const float* p = backend_->transfer_on_device(binding(), stats_);
  if (!p) throw DeviceError("this backend cannot leave the positions on the device");
  stats_.ms_total = ms_since(t0);
  return p;
}

std::vector<std::string> available_devices() {
  std::vector<std::string> d{"cpu"};
  if (cuda_available(nullptr)) d.push_back("cuda");
  return d;
}

}  // namespace larap
