// The paper's lattice hierarchy: coarser lattices above the fine one, solved coarse to fine.
//
// Level k joins 2x2x2 cells of level k-1 (Lattice::coarsened). Every level binds the handles
// (trilinearly, at their rest positions) and solves the same scale-free problem, so a large move
// reaches the fine level at once as an increment prolongated through the levels; the fine level
// then only adds detail. Coarse levels run on the CPU: they are 8^k times smaller and their
// increments travel to the finer level once per solve.
//
// This is the non-linear coarse-to-fine solve (flip-flop iterations on every level). The CUDA
// backend's linear multigrid, which preconditions one level's global step, is a separate idea and
// lives in native/cuda/.
#pragma once
#include <larap/lattice.h>
#include <larap/solve_stats.h>
#include <larap/mesh.h>

#include <array>
#include <memory>
#include <vector>

namespace larap {

class Backend;
struct HandleSpec;
struct HandleTargets;

class Hierarchy {
 public:
  Hierarchy();
  ~Hierarchy();
  Hierarchy(Hierarchy&&) noexcept;
  Hierarchy& operator=(Hierarchy&&) noexcept;

  // Up to levels - 1 coarser levels above `fine` (fewer when a level reaches a single cell), each
  // with its junction braces weighing `brace` (junction_braces.h; 0: none), as the fine level's.
  Hierarchy(const Lattice& fine, const RowMatrixX3d& vertices, int levels, double brace);

  // Number of coarse levels (0: the fine lattice alone).
  int size() const;
  // Nodes of coarse level `level` + 1 (0 <= level < size()).
  int64_t num_nodes(int level) const;

  // Binds the handles of `spec` (trilinearly, at their rest positions) on every coarse level.
  void set_handles(const HandleSpec& spec, double gamma, double size, const Eigen::Vector3d& origin);

  // Every coarse level back to its rest pose.
  void reset();
  // The coarse levels' poses (level 1 first), and putting them back (sizes checked by the caller).
  std::vector<RowMatrixX3d> poses() const;
  void set_poses(const std::vector<RowMatrixX3d>& poses);

  // Coarse to fine: each level takes the targets, chooses its start (warm_start.h, `still` and
  // `held_groups` as there) and iterates `iterations` times from its own pose plus the increment of the level
  // above. Returns the increment of level 1 prolongated to the fine lattice (#fine nodes by 3),
  // zero on the fine level's anchored nodes.
  RowMatrixX3d solve_increment(const HandleTargets& targets, int iterations,
                               const std::vector<uint8_t>& fine_anchored, double still,
                               const std::vector<uint8_t>& held_groups);

 private:
  struct Level;
  std::vector<Level> levels_;  // levels_[k] is level k+1 (cells 2^(k+1) times larger)
  double brace_ = 0.0;         // the junction braces' weight (make_handle_system)
};

}  // namespace larap
