// larap::Deformer — bind once, pose many times.
//
//   Deformer d(mesh, options);        // lattice + binding (+ backend)
//   d.set_handles({12, 40, 77});      // handle vertex ids; factorises the linear system
//   d.solve(targets, 5, out);         // targets: #handles by 3; out: #V by 3 positions
//
// Energy (scale-free gamma, see docs/method.md):
//   E = gamma * s^2 * mean_edges(|r_e|^2 / h^2) + mean_handles(|B_j c' - t_j|^2)
// where r_e is the ARAP residual of a directed lattice edge, h the cell size and s the radius
// of gyration of the rest vertices. The same gamma behaves the same at any model scale, lattice
// resolution and handle count: a uniform strain eps of the whole lattice costs as much as every
// handle missing its target by sqrt(gamma) * eps * s.
#pragma once
#include <larap/binding.h>
#include <larap/lattice.h>
#include <larap/mesh.h>

#include <array>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace larap {

struct DeformerOptions {
  LatticeOptions lattice;
  WeightKind weights = WeightKind::Trilinear;
  double gamma = 0.1;
  std::string device = "cpu";  // "cpu" | "cuda" | "auto"
  // Lattice levels solved coarse to fine (the paper's hierarchy); 1 = the fine lattice alone.
  int levels = 1;
};

struct SolveStats {
  std::vector<double> energy;  // energy after each flip-flop iteration (normalised, see above)
  int iterations = 0;
  bool rigid_carry = false;    // the previous pose was carried by the handles' best rigid motion
  double ms_rotations = 0, ms_rhs = 0, ms_solve = 0, ms_transfer = 0, ms_total = 0;
  double ms_energy = 0;        // evaluating the energy after each iteration
  double ms_start = 0;         // choosing the start (rigid carry, rest candidate)
  double ms_coarse = 0;        // the coarser levels of a hierarchy
  double ms_factorize = 0;     // last set_handles
  double ms_lattice = 0, ms_binding = 0;  // construction
  void clear_solve() {
    energy.clear();
    iterations = 0;
    rigid_carry = false;
    ms_rotations = ms_rhs = ms_solve = ms_transfer = ms_total = ms_energy = ms_start = ms_coarse = 0;
  }
};

class Backend;
struct HandleSystem;

class Deformer {
 public:
  Deformer(PolygonMesh mesh, const DeformerOptions& options);
  ~Deformer();
  Deformer(const Deformer&) = delete;
  Deformer& operator=(const Deformer&) = delete;

  // Handle vertex ids (unique, in range). An empty set is allowed: solve then gives the rest pose.
  void set_handles(const std::vector<int64_t>& indices);
  // Switch the weights; keeps the lattice pose and re-prepares the current handles.
  void set_weights(WeightKind kind);
  void set_gamma(double gamma);
  // Forget the pose: the next solve starts from rest.
  void reset();

  // targets: #handles by 3 row-major; out: #V by 3 row-major. Warm-starts from the last pose.
  // iterations: flip-flop steps; with tolerance > 0 it is the maximum, and the solve stops once
  // an iteration lowers the energy by less than tolerance * energy (converged).
  void solve(const double* targets, int iterations, double* out, double tolerance = 0.0);
  void solve(const double* targets, int iterations, float* out, double tolerance = 0.0);
  // The same solve, leaving the positions on the GPU: returns the device address of a #V by 3
  // float32 row-major array owned by the Deformer, valid until the next solve. Throws
  // DeviceError on the CPU backend.
  const float* solve_on_device(const double* targets, int iterations, double tolerance = 0.0);

  const Lattice& lattice() const { return lattice_; }
  const PolygonMesh& mesh() const { return mesh_; }
  RowMatrixX3d lattice_deformed() const;
  const std::vector<int64_t>& handles() const { return handles_; }
  WeightKind weights() const { return weights_; }
  double gamma() const { return gamma_; }
  double diagonal() const { return diagonal_; }
  std::string device() const;
  const SolveStats& stats() const { return stats_; }
  const Binding& binding() const;
  // Number of lattice levels actually built (coarsening stops at a single cell).
  int levels() const { return 1 + static_cast<int>(levels_.size()); }

  struct Level {  // a coarser lattice of the hierarchy (internal)
    Lattice lattice;
    std::unique_ptr<Backend> backend;
    std::vector<std::array<int32_t, 8>> prolong_ids;  // per node of the next finer level
    std::vector<std::array<double, 8>> prolong_w;
    std::vector<uint8_t> anchored;
    Level();
    Level(Level&&) noexcept;
    ~Level();
  };
  // Callers that use one Deformer from several threads lock this around each call (the Python
  // module does); the class itself is not thread-safe.
  std::mutex& mutex() const { return mutex_; }
  // Why device "auto" runs on the CPU although CUDA was tried (empty otherwise).
  const std::string& fallback_reason() const { return fallback_; }

 private:
  template <typename T>
  void solve_impl(const double* targets, int iterations, T* out, double tolerance);
  // Validation, warm start and iterations of a solve; false when there are no handles.
  bool pose_lattice(const double* targets, int iterations, double tolerance);
  void prepare_handles();
  void build_levels(int levels);
  HandleSystem handle_system(const Lattice& lat, int stencil, std::vector<int32_t> ids,
                             std::vector<double> weights) const;

  PolygonMesh mesh_;
  Lattice lattice_;
  WeightKind weights_;
  double gamma_;
  double diagonal_ = 1.0;  // bounding-box diagonal of the rest mesh
  double size_ = 1.0;      // radius of gyration of the rest vertices (the gamma's length scale)
  mutable std::unique_ptr<Binding> bindings_[2];
  std::unique_ptr<Backend> backend_;
  std::vector<int64_t> handles_;
  RowMatrixX3d rest_handles_;  // rest positions of the handles
  bool handles_set_ = false;
  bool auto_device_ = false;
  std::string fallback_;
  std::vector<Level> levels_;          // levels_[k] is level k+1 (cells 2^(k+1) times larger)
  std::vector<uint8_t> fine_anchored_;
  mutable std::mutex mutex_;
  SolveStats stats_;
};

// "cpu" always; "cuda" when built with CUDA and a device is usable.
std::vector<std::string> available_devices();

}  // namespace larap
