// larap::Deformer: owns the mesh, the lattice, the bindings, the fine level's backend and the
// coarse levels (hierarchy.h); a solve is a sequence of named steps (pose_lattice).
#include <larap/deformer.h>
#include <larap/errors.h>

#include <Eigen/LU>
#include <chrono>
#include <cmath>
#include <numeric>
#include <unordered_map>
#include <unordered_set>

#include "backend.h"
#include "handle_system.h"
#include "hierarchy.h"
#include "junction_braces.h"
#include "junction_stencils.h"
#include "warm_start.h"

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
  if (!(gamma >= kMinGamma && gamma <= kMaxGamma))
    throw InvalidInput("gamma must be between " + number_text(kMinGamma) + " and " + number_text(kMaxGamma) +
                       " (the default is " + number_text(DeformerOptions{}.gamma) + "), got " + number_text(gamma));
}

void check_junction_brace(double brace) {
  if (!(brace >= 0.0 && brace <= kMaxJunctionBrace))
    throw InvalidInput("junction_brace must be between 0 and " + number_text(kMaxJunctionBrace) + " (the default is " +
                       number_text(DeformerOptions{}.junction_brace) + "; 0 turns the braces off), got " +
                       number_text(brace));
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
  double brace;           // junction braces' weight (junction_braces.h)
  std::vector<std::array<int32_t, 3>> braces;  // the lattice's braces, found at bind (none when brace is 0)
  double diagonal = 1.0;  // bounding-box diagonal of the rest mesh
  double size = 1.0;      // radius of gyration of the rest vertices (the gamma's length scale)
  mutable std::unique_ptr<Binding> bindings[2];  // per weight kind, made on first use
  std::unique_ptr<Backend> backend;              // the fine level
  Hierarchy hierarchy;                           // the coarse levels
  HandleSpec spec;            // the handle vertices, their groups and weights, rest positions
  Eigen::Vector3d origin;     // centre of the rest lattice: centres the handle sums
  std::vector<uint8_t> fine_anchored;
  std::vector<std::array<int32_t, 2>> fine_group_components;  // (group, component) of the rows
  // The last solve's targets, to tell the groups the user kept where they were (warm_start.h):
  // the rest (identity maps, rest rows) while the lattice is at rest (construction, reset); the
  // last maps kept by a new handle set of as many groups; unknown after set_lattice_state, after
  // a solve that threw, or a new handle set otherwise (set_spec).
  enum class Last { Unknown, Rest, Maps, Rows } last = Last::Rest;
  bool at_rest = true;  // the lattice is at rest (construction, reset): the last targets were the rest
  std::vector<Affine34> last_maps;
  std::vector<double> last_rows;
  std::vector<Eigen::Vector4d> group_ball;  // per group: centre and radius of its rest rows
  bool handles_set = false;
  bool auto_device = false;
  std::string fallback;
  SolveStats stats;

  const Binding& binding() const { return binding_of(weights); }
  const Binding& binding_of(WeightKind kind) const {
    auto& slot = bindings[kind == WeightKind::Trilinear ? 0 : 1];
    if (!slot) {
      slot = std::make_unique<Binding>(bind_vertices(lattice, mesh.vertices, kind));
      resolve_junction_stencils(lattice, mesh, *slot);  // B-spline: each part's side of a junction
    }
    return *slot;
  }

  void set_spec(HandleSpec next);
  void prepare_handles();
  void replace_backend_with_cpu(const HandleSystem& hs, const OutOfMemory& why);
  bool pose_lattice(const HandleTargets& targets, int iterations, double tolerance);
  void check_solve_args(const HandleTargets& targets, int iterations, double tolerance) const;
  std::vector<uint8_t> held_groups(const HandleTargets& targets) const;
  void remember(const HandleTargets& targets);
  void choose_start(const std::vector<uint8_t>& held);
  void coarse_to_fine(const HandleTargets& targets, int iterations, const std::vector<uint8_t>& held);
  void iterate_fine(int iterations, double tolerance);
  template <typename T>
  void solve(const HandleTargets& targets, int iterations, T* out, double tolerance);
  HandleTargets rows(const double* targets) const { return HandleTargets{targets, nullptr}; }
  HandleTargets maps(const double* transforms, std::vector<Affine34>& storage) const;
};

// ------------------------------------------------------------------------------------ construction
Deformer::Deformer(PolygonMesh mesh, const DeformerOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  check_gamma(options.gamma);
  check_levels(options.levels);
  check_junction_brace(options.junction_brace);
  d.mesh = std::move(mesh);
  d.weights = options.weights;
  d.gamma = options.gamma;
  d.brace = options.junction_brace;
  validate_mesh(d.mesh);
  auto t0 = Clock::now();
  d.lattice = Lattice::build(d.mesh, options.lattice);
  if (d.brace > 0.0) d.braces = larap::junction_braces(d.lattice);
  d.stats.ms_lattice = ms_since(t0);
  const RowMatrixX3d& V = d.mesh.vertices;
  const Eigen::Vector3d ext = (V.colwise().maxCoeff() - V.colwise().minCoeff()).transpose();
  d.diagonal = ext.norm() > 0.0 ? ext.norm() : d.lattice.h;
  const Eigen::RowVector3d centroid = V.colwise().mean();
  // The handle sums are centred at the lattice's centre (the CUDA backend keeps its float frame there).
  d.origin = 0.5 * (d.lattice.rest.colwise().minCoeff() + d.lattice.rest.colwise().maxCoeff()).transpose();
  d.size = std::sqrt((V.rowwise() - centroid).rowwise().squaredNorm().mean());
  if (!(d.size > 0.0)) d.size = d.lattice.h;
  t0 = Clock::now();
  d.binding();
  d.stats.ms_binding = ms_since(t0);
  d.backend = make_backend(options.device, d.lattice, V, d.fallback);
  d.auto_device = options.device == "auto";
  d.hierarchy = Hierarchy(d.lattice, V, options.levels, d.brace);
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
  HandleSpec spec;  // one group per vertex
  spec.vertices = indices;
  spec.group_offsets.resize(indices.size() + 1);
  std::iota(spec.group_offsets.begin(), spec.group_offsets.end(), int64_t(0));
  d.set_spec(std::move(spec));
}

void Deformer::set_handle_groups(const std::vector<std::vector<int64_t>>& groups,
                                 const std::vector<double>& group_weights,
                                 const std::vector<std::vector<double>>& vertex_weights) {
  Impl& d = *impl_;
  const int64_t n = d.mesh.num_vertices();
  const size_t G = groups.size();
  if (!group_weights.empty() && group_weights.size() != G)
    throw InvalidInput("weights has " + std::to_string(group_weights.size()) + " entries for " +
                       std::to_string(G) + " groups");
  if (!vertex_weights.empty() && vertex_weights.size() != G)
    throw InvalidInput("vertex_weights has " + std::to_string(vertex_weights.size()) +
                       " arrays for " + std::to_string(G) + " groups");
  HandleSpec spec;
  spec.group_offsets.push_back(0);
  std::unordered_map<int64_t, size_t> owner;  // vertex -> group
  for (size_t g = 0; g < G; ++g) {
    const auto& ids = groups[g];
    if (!group_weights.empty() && !(group_weights[g] >= 0.0 && std::isfinite(group_weights[g])))
      throw InvalidInput("weights[" + std::to_string(g) + "] must be a non-negative finite number, got " +
                         std::to_string(group_weights[g]));
    if (!vertex_weights.empty() && vertex_weights[g].size() != ids.size())
      throw InvalidInput("vertex_weights[" + std::to_string(g) + "] has " +
                         std::to_string(vertex_weights[g].size()) + " entries for the " +
                         std::to_string(ids.size()) + " vertices of group " + std::to_string(g));
    for (size_t k = 0; k < ids.size(); ++k) {
      const int64_t v = ids[k];
      if (v < 0 || v >= n)
        throw InvalidInput("group " + std::to_string(g) + " holds vertex " + std::to_string(v) +
                           ", out of range for " + std::to_string(n) + " vertices");
      const auto [it, fresh] = owner.emplace(v, g);
      if (!fresh)
        throw InvalidInput("vertex " + std::to_string(v) + " is in group " + std::to_string(it->second) +
                           (it->second == g ? " twice" : " and in group " + std::to_string(g)) +
                           ": handle groups must be disjoint");
      if (!vertex_weights.empty()) {
        const double w = vertex_weights[g][k];
        if (!(w >= 0.0 && std::isfinite(w)))
          throw InvalidInput("vertex_weights[" + std::to_string(g) + "][" + std::to_string(k) +
                             "] must be a non-negative finite number, got " + std::to_string(w));
        spec.omega.push_back(w);
      }
      spec.vertices.push_back(v);
    }
    spec.group_offsets.push_back(int64_t(spec.vertices.size()));
  }
  spec.group_weights = group_weights;
  d.set_spec(std::move(spec));
}

void Deformer::Impl::set_spec(HandleSpec next) {
  next.rest.resize(int64_t(next.vertices.size()), 3);
  for (size_t j = 0; j < next.vertices.size(); ++j) next.rest.row(j) = mesh.vertices.row(next.vertices[j]);
  HandleSpec previous = std::move(spec);
  const bool was_set = handles_set;
  spec = std::move(next);
  handles_set = true;
  try {
    prepare_handles();
  } catch (...) {  // the Deformer stays usable with the handles it had
    spec = std::move(previous);
    handles_set = was_set;
    if (handles_set) prepare_handles();
    throw;
  }
  // New groups: the last targets are their rest when the lattice is at rest; with a posed lattice
  // the same number of groups keeps the last maps (a weight or membership changed: each group's
  // map is still its own), anything else is unknown. Each group's ball bounds how far a change
  // of its map moves its rows (held_groups).
  const int64_t G = int64_t(spec.group_offsets.size()) - 1;
  if (at_rest) last = Last::Rest;
  else if (!(last == Last::Maps && int64_t(last_maps.size()) == G)) last = Last::Unknown;
  if (last != Last::Maps) last_maps.clear();
  last_rows.clear();
  group_ball.assign(size_t(std::max<int64_t>(G, 0)), Eigen::Vector4d::Zero());
  for (int64_t g = 0; g < G; ++g) {
    const int64_t a = spec.group_offsets[g], b = spec.group_offsets[g + 1];
    if (a == b) continue;
    const Eigen::Vector3d c = spec.rest.middleRows(a, b - a).colwise().mean().transpose();
    double r = 0.0;
    for (int64_t j = a; j < b; ++j) r = std::max(r, (spec.rest.row(j).transpose() - c).norm());
    group_ball[size_t(g)] << c, r;
  }
}

void Deformer::set_weights(WeightKind kind) {
  Impl& d = *impl_;
  if (kind == d.weights) return;
  d.weights = kind;  // the handle rows are trilinear with either kind: nothing to re-prepare
}

void Deformer::set_gamma(double gamma) {
  Impl& d = *impl_;
  check_gamma(gamma);
  const double previous = d.gamma;
  d.gamma = gamma;
  if (!d.handles_set) return;
  try {
    d.prepare_handles();
  } catch (...) {  // the Deformer stays usable with the gamma it had
    d.gamma = previous;
    d.prepare_handles();
    throw;
  }
}

void Deformer::reset() {
  impl_->backend->set_pose(impl_->lattice.rest);
  impl_->hierarchy.reset();
  impl_->last = Impl::Last::Rest;
  impl_->at_rest = true;
}

void Deformer::Impl::prepare_handles() {
  const auto t0 = Clock::now();
  // Handle rows are trilinear over the real cells with either weight kind, so the lattice pose
  // does not depend on the weights (the B-spline only changes the transfer; docs/method.md).
  const Binding& b = binding_of(WeightKind::Trilinear);
  const int s = b.stencil_size();
  const int64_t mh = static_cast<int64_t>(spec.vertices.size());
  std::vector<int32_t> ids(size_t(mh) * s);
  std::vector<double> w(ids.size());
  for (int64_t j = 0; j < mh; ++j) b.weights_of(lattice, spec.vertices[j], &ids[j * s], &w[j * s]);
  HandleSystem hs = make_handle_system(lattice, s, std::move(ids), std::move(w), spec, gamma, braces, brace, size,
                                       origin);
  fine_anchored = hs.anchored;
  fine_group_components = group_components(hs);
  hierarchy.set_handles(spec, gamma, size, origin);
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
  impl_->solve(impl_->rows(targets), iterations, out, tolerance);
}
void Deformer::solve(const double* targets, int iterations, float* out, double tolerance) {
  impl_->solve(impl_->rows(targets), iterations, out, tolerance);
}
void Deformer::solve_transforms(const double* transforms, int iterations, double* out, double tolerance) {
  std::vector<Affine34> maps;
  impl_->solve(impl_->maps(transforms, maps), iterations, out, tolerance);
}
void Deformer::solve_transforms(const double* transforms, int iterations, float* out, double tolerance) {
  std::vector<Affine34> maps;
  impl_->solve(impl_->maps(transforms, maps), iterations, out, tolerance);
}

void Deformer::pose(const double* targets, int iterations, double tolerance) {
  impl_->pose_lattice(impl_->rows(targets), iterations, tolerance);
}
void Deformer::pose_transforms(const double* transforms, int iterations, double tolerance) {
  std::vector<Affine34> maps;
  impl_->pose_lattice(impl_->maps(transforms, maps), iterations, tolerance);
}

const float* Deformer::solve_on_device(const double* targets, int iterations, double tolerance,
                                       bool transforms) {
  Impl& d = *impl_;
  if (d.backend->name() == "cpu")
    throw DeviceError("solve_on_device needs the CUDA backend; this Deformer runs on the CPU");
  const auto t0 = Clock::now();
  std::vector<Affine34> maps;
  d.pose_lattice(transforms ? d.maps(targets, maps) : d.rows(targets), iterations, tolerance);
  const float* p = d.backend->transfer_on_device(d.binding(), d.stats);
  if (!p) throw DeviceError("this backend cannot leave the positions on the device");
  d.stats.ms_total = ms_since(t0);
  return p;
}

// G 4x4 row-major affine maps, checked: finite, last row (0, 0, 0, 1), not singular.
HandleTargets Deformer::Impl::maps(const double* transforms, std::vector<Affine34>& storage) const {
  if (!handles_set) throw StateError("solve() needs set_handles() or set_handle_groups() first");
  const int64_t G = static_cast<int64_t>(spec.group_offsets.size()) - 1;
  storage.resize(size_t(G));
  for (int64_t g = 0; g < G; ++g) {
    const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> T(transforms + 16 * g);
    const std::string name = "transforms[" + std::to_string(g) + "]";
    if (!T.allFinite()) throw InvalidInput(name + " has a non-finite entry");
    const double scale = std::max(1.0, T.cwiseAbs().maxCoeff());
    if ((T.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-9 * scale)
      throw InvalidInput(name + " is not affine: its last row must be (0, 0, 0, 1)");
    const Eigen::Matrix3d A = T.topLeftCorner<3, 3>();
    const double norm = A.norm() / std::sqrt(3.0);
    if (!(std::abs(A.determinant()) > 1e-9 * norm * norm * norm))
      throw InvalidInput(name + " is singular (its 3x3 part has determinant " +
                         std::to_string(A.determinant()) + ")");
    storage[g] = T.topRows<3>();
  }
  return HandleTargets{nullptr, storage.data()};
}

template <typename T>
void Deformer::Impl::solve(const HandleTargets& targets, int iterations, T* out, double tolerance) {
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
bool Deformer::Impl::pose_lattice(const HandleTargets& targets, int iterations, double tolerance) {
  check_solve_args(targets, iterations, tolerance);
  const auto t0 = Clock::now();
  stats.clear_solve();
  if (spec.vertices.empty()) return false;
  backend->set_targets(targets);
  const std::vector<uint8_t> held = held_groups(targets);
  last = Last::Unknown;  // until this solve ends (an exception leaves the pose between targets)
  at_rest = false;
  choose_start(held);
  stats.ms_start = ms_since(t0);
  coarse_to_fine(targets, iterations, held);
  iterate_fine(iterations, tolerance);
  remember(targets);
  stats.ms_total = ms_since(t0);
  return true;
}

// Per group, 1 when its targets moved less than 1e-7 of the model's size since the last solve
// (the `still` of choose_start): a group the user kept where it was. Empty when unknown. O(G) for
// maps (a change of map moves a row of the group's rest ball, centre c and radius r, at most
// |dA c + db| + |dA|_F r), O(rows) for row targets.
std::vector<uint8_t> Deformer::Impl::held_groups(const HandleTargets& targets) const {
  const double still = 1e-7 * diagonal;
  const int64_t G = int64_t(spec.group_offsets.size()) - 1;
  std::vector<uint8_t> held;
  if (last == Last::Unknown || (last == Last::Maps && !targets.groups) || (last == Last::Rows && !targets.rows))
    return held;
  held.assign(size_t(G), 0);
  for (int64_t g = 0; g < G; ++g) {
    if (targets.groups) {
      Affine34 before = Affine34::Zero();
      before.leftCols<3>().setIdentity();  // Last::Rest
      if (last == Last::Maps) before = last_maps[size_t(g)];
      const Affine34 d = targets.groups[g] - before;
      const Eigen::Vector4d& ball = group_ball[size_t(g)];
      const double moved = (d.leftCols<3>() * ball.head<3>() + d.col(3)).norm() + d.leftCols<3>().norm() * ball[3];
      held[size_t(g)] = moved <= still;
    } else {
      bool kept = true;
      for (int64_t j = spec.group_offsets[g]; kept && j < spec.group_offsets[g + 1]; ++j) {
        const Eigen::Vector3d t(targets.rows + 3 * j);
        const Eigen::Vector3d before = last == Last::Rows ? Eigen::Vector3d(last_rows.data() + 3 * j)
                                                          : Eigen::Vector3d(spec.rest.row(j).transpose());
        kept = (t - before).norm() <= still;
      }
      held[size_t(g)] = kept;
    }
  }
  return held;
}

void Deformer::Impl::remember(const HandleTargets& targets) {
  if (targets.groups) {
    last_maps.assign(targets.groups, targets.groups + (spec.group_offsets.size() - 1));
    last = Last::Maps;
  } else {
    last_rows.assign(targets.rows, targets.rows + 3 * spec.vertices.size());
    last = Last::Rows;
  }
}

void Deformer::Impl::check_solve_args(const HandleTargets& targets, int iterations, double tolerance) const {
  if (!handles_set) throw StateError("solve() needs set_handles() or set_handle_groups() first");
  if (iterations < 0 || iterations > kMaxIterations)
    throw InvalidInput("iterations must be between 0 and " + std::to_string(kMaxIterations) +
                       ", got " + std::to_string(iterations));
  if (!(tolerance >= 0.0) || !std::isfinite(tolerance))
    throw InvalidInput("tolerance must be a non-negative number, got " + number_text(tolerance));
  if (targets.rows) {
    const int64_t m = static_cast<int64_t>(spec.vertices.size());
    for (int64_t k = 0; k < 3 * m; ++k)
      if (!std::isfinite(targets.rows[k]))
        throw InvalidInput("targets[" + std::to_string(k / 3) + "] has a non-finite coordinate");
  }
}

// Per lattice component (warm_start.h); handles that miss by less than 1e-7 of the model's size
// count as not moved.
void Deformer::Impl::choose_start(const std::vector<uint8_t>& held) {
  warm_start(*backend, 1e-7 * diagonal, stats,
             held_components(fine_group_components, held, lattice.num_components));
}

// Coarse to fine: the coarse levels' increment is added to the fine level's previous pose, so
// fine detail of the previous pose is kept and large-scale motion arrives at once.
void Deformer::Impl::coarse_to_fine(const HandleTargets& targets, int iterations, const std::vector<uint8_t>& held) {
  if (hierarchy.size() == 0) return;
  const auto t0 = Clock::now();
  const RowMatrixX3d increment = hierarchy.solve_increment(targets, iterations, fine_anchored, 1e-7 * diagonal, held);
  RowMatrixX3d fine;
  backend->get_pose(fine);
  backend->set_pose(fine + increment);
  stats.ms_coarse = ms_since(t0);
}

void Deformer::Impl::iterate_fine(int iterations, double tolerance) {
  if (tolerance <= 0.0) {
    backend->iterate(iterations, stats);
    stats.iterations = iterations;
    return;
  }
  // In chunks, so that a backend keeps its fused multi-iteration path.
  int done = 0;
  while (done < iterations) {
    const int chunk = std::min(5, iterations - done);
    backend->iterate(chunk, stats);
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
std::vector<RowMatrixX3d> Deformer::lattice_state() const {
  std::vector<RowMatrixX3d> state{lattice_deformed()};
  for (RowMatrixX3d& coarse : impl_->hierarchy.poses()) state.push_back(std::move(coarse));
  return state;
}

void Deformer::set_lattice_state(const std::vector<RowMatrixX3d>& state) {
  Impl& d = *impl_;
  const int levels = 1 + d.hierarchy.size();
  if (int64_t(state.size()) != levels)
    throw InvalidInput("lattice state: " + std::to_string(state.size()) + " levels given, this Deformer has " +
                       std::to_string(levels));
  for (int l = 0; l < levels; ++l) {
    const int64_t n = l == 0 ? d.lattice.num_nodes() : d.hierarchy.num_nodes(l - 1);
    if (state[size_t(l)].rows() != n)
      throw InvalidInput("lattice state: level " + std::to_string(l) + " has " +
                         std::to_string(state[size_t(l)].rows()) + " nodes, expected " + std::to_string(n));
    if (!state[size_t(l)].allFinite())
      throw InvalidInput("lattice state: level " + std::to_string(l) + " has a non-finite coordinate");
  }
  d.backend->set_pose(state[0]);
  d.hierarchy.set_poses(std::vector<RowMatrixX3d>(state.begin() + 1, state.end()));
  d.last = Impl::Last::Unknown;  // the targets of this pose are not known
  d.at_rest = false;
}

RowMatrixX3d Deformer::lattice_deformed() const {
  RowMatrixX3d p;
  impl_->backend->get_pose(p);
  return p;
}
const std::vector<int64_t>& Deformer::handles() const { return impl_->spec.vertices; }
int64_t Deformer::num_groups() const { return int64_t(impl_->spec.group_offsets.size()) - 1; }
WeightKind Deformer::weights() const { return impl_->weights; }
double Deformer::gamma() const { return impl_->gamma; }
double Deformer::junction_brace() const { return impl_->brace; }
std::vector<std::array<int32_t, 3>> Deformer::junction_braces() const { return impl_->braces; }
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
