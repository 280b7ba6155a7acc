// larap::Deformer — bind once, pose many times.
//
//   Deformer d(mesh, options);          // lattice + binding (+ backend)
//   d.set_handle_groups({hand, foot});  // vertex groups; factorises the linear system
//   d.solve_transforms(T, 5, out);      // T: one 4x4 affine map per group; out: #V by 3 positions
// or, one target per handle vertex:
//   d.set_handles({12, 40, 77});        // = three groups of one vertex
//   d.solve(targets, 5, out);           // targets: #handles by 3
//
// Energy (scale-free gamma, see docs/method.md):
//   E = gamma * s^2 * wmean_edges(|r_e|^2 / h^2) + sum_groups (w_g / G) * wmean_{j in g} |B_j c' - t_j|^2
// where r_e is the ARAP residual of a directed lattice edge (weighted by the edge's weight, 1
// except on the edges of split cells: lattice.h), h the cell size, s the radius of
// gyration of the rest vertices, w_g a group's weight and wmean the mean over its vertices
// weighted by the vertex weights. The same gamma behaves the same at any model scale, lattice
// resolution and handle count, and a group pulls with its own weight whatever its size.
//
// Not thread-safe: a caller that shares one Deformer between threads serialises the calls (the
// Python module does, per instance).
#pragma once
#include <larap/binding.h>
#include <larap/lattice.h>
#include <larap/mesh.h>
#include <larap/solve_stats.h>

#include <array>
#include <memory>
#include <string>
#include <vector>

namespace larap {

// ------------------------------------------------------------------------------------ limits
constexpr int kMaxLevels = 8;             // DeformerOptions::levels is in [1, kMaxLevels]
constexpr int kMaxIterations = 100000;    // solve(..., iterations) is in [0, kMaxIterations]
// gamma is in [kMinGamma, kMaxGamma]: beyond, the system is too ill-conditioned in double to give
// back the rest pose (measured on a sphere: 1e-12 leaves 1.6e-5 of its radius, 1e12 1e-4;
// within, at most 2e-7), or not positive definite at all.
constexpr double kMinGamma = 1e-8;
constexpr double kMaxGamma = 1e8;
constexpr double kMaxJunctionBrace = 1e4;  // DeformerOptions::junction_brace is in [0, kMaxJunctionBrace]

// ------------------------------------------------------------------------------------ options
struct DeformerOptions {
  LatticeOptions lattice;                       // resolution and memory limit of the lattice
  WeightKind weights = WeightKind::Trilinear;   // vertex binding used by solve()
  double gamma = 0.03;                          // rigidity, scale-free ([kMinGamma, kMaxGamma]; docs/method.md)
  std::string device = "cpu";                   // "cpu" | "cuda" | "auto"
  int levels = 1;                               // lattice levels solved coarse to fine; 1 = fine only
  // Braces where the solid branches (a palm's end holding every finger's root, a fork's joint):
  // weight per unit of the lattice's stiffness, [0, kMaxJunctionBrace]; 0 = none (docs/method.md,
  // "Junction braces").
  double junction_brace = 50.0;
};

class Deformer {
 public:
  // ---------------------------------------------------------------------------- construction
  // Builds the lattice of `mesh` and binds its vertices. Throws InvalidInput (bad mesh or
  // options), OutOfMemory (the lattice would not fit), DeviceError (device not available).
  Deformer(PolygonMesh mesh, const DeformerOptions& options);
  ~Deformer();
  Deformer(const Deformer&) = delete;
  Deformer& operator=(const Deformer&) = delete;

  // ---------------------------------------------------------------------------- handles
  // Handle vertex ids (unique, in range). Factorises the linear system once per set. An empty
  // set is allowed: solve then gives the rest pose.
  void set_handles(const std::vector<int64_t>& indices);
  // Handle groups: disjoint vertex id lists (a vertex in two groups is InvalidInput), each moved
  // by one transform at solve time. group_weights: one pull strength per group (>= 0, empty = all
  // 1); vertex_weights: per group, one weight per vertex (>= 0, empty = all 1; a soft falloff at a
  // group's edge). Factorises like set_handles. handles() lists the vertices group by group.
  void set_handle_groups(const std::vector<std::vector<int64_t>>& groups,
                         const std::vector<double>& group_weights = {},
                         const std::vector<std::vector<double>>& vertex_weights = {});
  // Switch the weights; keeps the lattice pose and re-prepares the current handles.
  void set_weights(WeightKind kind);
  void set_gamma(double gamma);
  // Forget the pose: the next solve starts from rest.
  void reset();
  // The lattice pose of every level (the fine level first, then the hierarchy's coarser ones), and
  // putting it back: a cancelled drag returns the engine to where the solve before it ended, so the
  // next solve warm-starts there instead of from rest. set_lattice_state throws InvalidInput (and
  // changes nothing) unless `state` has one #N by 3 array per level of this Deformer, all finite;
  // the fine level's stencil-shell rows are checked but recomputed from its real nodes.
  std::vector<RowMatrixX3d> lattice_state() const;
  void set_lattice_state(const std::vector<RowMatrixX3d>& state);

  // ---------------------------------------------------------------------------- posing
  // targets: #handles by 3 row-major; out: #V by 3 row-major. Warm-starts from the last pose.
  // iterations: flip-flop steps; with tolerance > 0 it is the maximum, and the solve stops once
  // an iteration lowers the energy by less than tolerance * energy (converged).
  void solve(const double* targets, int iterations, double* out, double tolerance = 0.0);
  void solve(const double* targets, int iterations, float* out, double tolerance = 0.0);
  // The same with one affine map per group: transforms is #groups by 4 by 4 row-major (each
  // group's targets are its rest positions mapped by its transform). Nothing per pose costs in
  // proportion to the handle vertices.
  void solve_transforms(const double* transforms, int iterations, double* out, double tolerance = 0.0);
  void solve_transforms(const double* transforms, int iterations, float* out, double tolerance = 0.0);
  // The same solve without the transfer to the vertices: only the lattice is posed (read it with
  // lattice_deformed()). For drawing the pose from the lattice (a GPU preview).
  void pose(const double* targets, int iterations, double tolerance = 0.0);
  void pose_transforms(const double* transforms, int iterations, double tolerance = 0.0);
  // The same solve, leaving the positions on the GPU: returns the device address of a #V by 3
  // float32 row-major array owned by the Deformer, valid until the next solve. Throws
  // DeviceError on the CPU backend. transforms: `targets` holds the groups' 4x4 maps.
  const float* solve_on_device(const double* targets, int iterations, double tolerance = 0.0,
                               bool transforms = false);

  // ---------------------------------------------------------------------------- inspection
  const Lattice& lattice() const;
  const PolygonMesh& mesh() const;
  const Binding& binding() const;          // of the current weight kind
  RowMatrixX3d lattice_deformed() const;   // #N by 3 node positions of the current pose
  const std::vector<int64_t>& handles() const;
  int64_t num_groups() const;              // handle groups (set_handles: one per vertex)
  WeightKind weights() const;
  double gamma() const;
  double junction_brace() const;
  // The braced columns (a, b, c), a < c, of the fine lattice's real nodes, held straight by junction_brace
  // where the solid branches; empty when junction_brace is 0 or nothing branches.
  std::vector<std::array<int32_t, 3>> junction_braces() const;
  double diagonal() const;                 // bounding-box diagonal of the rest mesh
  std::string device() const;              // the backend that runs: "cpu" or "cuda"
  const std::string& fallback_reason() const;  // why device "auto" runs on the CPU (else empty)
  int levels() const;                      // lattice levels built (coarsening stops at one cell)
  const SolveStats& stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// "cpu" always; "cuda" when built with CUDA and a device is usable.
std::vector<std::string> available_devices();

}  // namespace larap
