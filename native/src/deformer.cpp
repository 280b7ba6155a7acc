#include <larap/deformer.h>
#include <larap/errors.h>

#include <chrono>
#include <cmath>
#include <unordered_set>

#include "backend.h"
#include "rigid_fit.h"

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
  if (options.levels < 1 || options.levels > 8)
    throw InvalidInput("levels must be between 1 and 8, got " + std::to_string(options.levels));
  build_levels(options.levels);
}

Deformer::~Deformer() = default;
Deformer::Level::Level() = default;
Deformer::Level::Level(Level&&) noexcept = default;
Deformer::Level::~Level() = default;

const Binding& Deformer::binding() const {
  auto& slot = bindings_[weights_ == WeightKind::Trilinear ? 0 : 1];
  if (!slot) slot = std::make_unique<Binding>(bind_vertices(lattice_, mesh_.vertices, weights_));
  return *slot;
}

std::string Deformer::device() const { return backend_->name(); }

void Deformer::build_levels(int levels) {
  // Level k joins 2x2x2 cells of level k-1. Coarse levels always run on the CPU: they are 8^k
  // times smaller, and only their increments travel to the finer level, once per solve.
  levels_.reserve(size_t(levels));  // `finer` points into levels_: no reallocation
  const Lattice* finer = &lattice_;
  for (int k = 1; k < levels; ++k) {
    if (finer->num_cells() <= 1) break;
    levels_.emplace_back();
    Level& lv = levels_.back();
    lv.lattice = finer->coarsened();
    // Prolongation: every node of the finer level as a trilinear combination of this level's
    // nodes, through the parent of a kept finer cell that has the node as a corner.
    const int64_t nf = finer->num_nodes();
    lv.prolong_ids.assign(size_t(nf), {});
    lv.prolong_w.assign(size_t(nf), {});
    std::vector<uint8_t> done(size_t(nf), 0);
    for (int64_t c = 0; c < finer->num_cells(); ++c) {
      const Eigen::Vector3i parent = finer->cell_coords[c] / 2;
      const int32_t pc = lv.lattice.cell_at(parent.x(), parent.y(), parent.z());
      for (int corner = 0; corner < 8; ++corner) {
        const int32_t i = finer->cell_nodes[c][corner];
        if (done[i]) continue;
        done[i] = 1;
        const Eigen::Vector3d f = 0.5 * (finer->node_coords[i] - 2 * parent).cast<double>();  // in [0,1]
        for (int q = 0; q < 8; ++q) {
          lv.prolong_ids[i][q] = lv.lattice.cell_nodes[pc][q];
          lv.prolong_w[i][q] = ((q & 1) ? f.x() : 1 - f.x()) * (((q >> 1) & 1) ? f.y() : 1 - f.y()) *
                               ((q >> 2) ? f.z() : 1 - f.z());
        }
      }
    }
    lv.backend = make_cpu_backend(lv.lattice, mesh_.vertices);
    finer = &lv.lattice;
  }
}

// The finer level's displacement for an increment `delta` of level `lv` (its nodes), zero on the
// finer level's anchored nodes.
RowMatrixX3d prolong(const Deformer::Level& lv, const RowMatrixX3d& delta,
                            const std::vector<uint8_t>& finer_anchored) {
  const int64_t nf = static_cast<int64_t>(lv.prolong_ids.size());
  RowMatrixX3d out = RowMatrixX3d::Zero(nf, 3);
  for (int64_t i = 0; i < nf; ++i) {
    if (!finer_anchored.empty() && finer_anchored[i]) continue;
    for (int q = 0; q < 8; ++q) out.row(i) += lv.prolong_w[i][q] * delta.row(lv.prolong_ids[i][q]);
  }
  return out;
}

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

void Deformer::reset() {
  backend_->set_pose(lattice_.rest);
  for (auto& lv : levels_) lv.backend->set_pose(lv.lattice.rest);
}

RowMatrixX3d Deformer::lattice_deformed() const {
  RowMatrixX3d p;
  backend_->get_pose(p);
  return p;
}

HandleSystem Deformer::handle_system(const Lattice& lat, int stencil, std::vector<int32_t> ids,
                                     std::vector<double> weights) const {
  HandleSystem hs;
  hs.m = static_cast<int64_t>(handles_.size());
  hs.stencil = stencil;
  hs.ids = std::move(ids);
  hs.weights = std::move(weights);

  // Scale-free gamma: E = gamma * s^2 * mean_e(|r_e|^2 / h^2) + mean_j |B_j c' - t_j|^2, with s
  // the radius of gyration of the rest vertices. Multiplying by m gives the paper's form with
  // gamma_eff = gamma * m * s^2 / (h^2 * #directed edges). A uniform strain eps of the whole
  // lattice costs as much as every handle missing its target by sqrt(gamma) * eps * s. The same
  // definition on every level of a hierarchy makes the levels solve the same problem.
  const double m = std::max<int64_t>(hs.m, 1);
  const double directed = std::max<double>(1.0, 2.0 * double(lat.edges.size()));
  const double s = size_, h = lat.h;
  hs.gamma_eff = gamma_ * m * s * s / (h * h * directed);
  hs.energy_scale = 1.0 / (m * s * s);

  // Components without a handle stay at rest (their system would be singular otherwise).
  std::vector<uint8_t> has_handle(size_t(lat.num_components), 0);
  for (int64_t j = 0; j < hs.m; ++j)
    for (int k = 0; k < hs.stencil; ++k)
      if (hs.weights[j * hs.stencil + k] != 0.0)
        has_handle[lat.component[hs.ids[j * hs.stencil + k]]] = 1;
  const int64_t nn = lat.num_nodes();
  hs.anchored.resize(size_t(nn));
  for (int64_t i = 0; i < nn; ++i) hs.anchored[i] = has_handle[lat.component[i]] ? 0 : 1;
  hs.anchor_weight = 2.0 * hs.gamma_eff;
  return hs;
}

void Deformer::prepare_handles() {
  const auto t0 = Clock::now();
  const Binding& b = binding();
  const int64_t mh = static_cast<int64_t>(handles_.size());
  std::vector<int32_t> ids(size_t(mh) * b.stencil_size());
  std::vector<double> w(ids.size());
  for (int64_t j = 0; j < mh; ++j)
    b.weights_of(lattice_, handles_[j], &ids[j * b.stencil_size()], &w[j * b.stencil_size()]);
  HandleSystem hs = handle_system(lattice_, b.stencil_size(), std::move(ids), std::move(w));
  fine_anchored_ = hs.anchored;

  // Coarser levels: the handles bound trilinearly to each level's lattice.
  for (auto& lv : levels_) {
    lv.anchored.clear();
    if (mh == 0) continue;
    const Binding hb = bind_vertices(lv.lattice, rest_handles_, WeightKind::Trilinear);
    std::vector<int32_t> cids(size_t(mh) * 8);
    std::vector<double> cw(cids.size());
    for (int64_t j = 0; j < mh; ++j) hb.weights_of(lv.lattice, j, &cids[j * 8], &cw[j * 8]);
    HandleSystem chs = handle_system(lv.lattice, 8, std::move(cids), std::move(cw));
    lv.anchored = chs.anchored;
    lv.backend->set_handles(chs);
  }

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
    for (auto& lv : levels_) lv.backend->apply_rigid(R, t);
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
    if (!(e_rest < e_prev)) {
      backend_->set_pose(prev);
    } else {
      for (auto& lv : levels_) {
        lv.backend->set_pose(lv.lattice.rest);
        lv.backend->apply_rigid(R0, t0r);
      }
    }
  }
  stats_.ms_start = ms_since(t0);

  // Coarse to fine: each coarser level iterates from its own previous pose plus the increment of
  // the level below it; the finest level starts from its previous pose plus the increment of
  // level 1. Fine detail of the previous pose is kept, large-scale motion arrives at once.
  if (!levels_.empty()) {
    const auto tc = Clock::now();
    SolveStats scratch;
    RowMatrixX3d delta;  // increment of the level just solved, in its nodes
    for (int l = int(levels_.size()) - 1; l >= 0; --l) {
      Level& lv = levels_[l];
      RowMatrixX3d start;
      lv.backend->get_pose(start);
      if (l + 1 < int(levels_.size())) {
        lv.backend->set_pose(start + prolong(levels_[l + 1], delta, lv.anchored));
      }
      lv.backend->iterate(tgt, std::max(iterations, 1), scratch);
      RowMatrixX3d after;
      lv.backend->get_pose(after);
      delta = after - start;
    }
    RowMatrixX3d fine;
    backend_->get_pose(fine);
    backend_->set_pose(fine + prolong(levels_[0], delta, fine_anchored_));
    stats_.ms_coarse = ms_since(tc);
  }
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
