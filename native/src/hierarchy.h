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
#include <larap/mesh.h>

#include <array>
#include <memory>
#include <vector>

namespace larap {

class Backend;

class Hierarchy {
 public:
  Hierarchy();
  ~Hierarchy();
  Hierarchy(Hierarchy&&) noexcept;
  Hierarchy& operator=(Hierarchy&&) noexcept;

  // Up to levels - 1 coarser levels above `fine` (fewer when a level reaches a single cell).
  // `fine` must outlive the hierarchy.
  Hierarchy(const Lattice& fine, const RowMatrixX3d& vertices, int levels);

  // Number of coarse levels (0: the fine lattice alone).
  int size() const;

  // Binds handles with rest positions `rest_handles` (m by 3) on every coarse level.
  void set_handles(const RowMatrixX3d& rest_handles, double gamma, double size);

  // Every coarse level back to its rest pose.
  void reset();
  // x -> R x + t on every coarse level's free nodes (a rigid carry of the previous pose).
  void apply_rigid(const Eigen::Matrix3d& R, const Eigen::Vector3d& t);
  // Every coarse level to its rest pose moved by x -> R x + t.
  void restart_rigid(const Eigen::Matrix3d& R, const Eigen::Vector3d& t);

  // Coarse to fine: each level iterates `iterations` times from its own previous pose plus the
  // increment of the level above. Returns the increment of level 1 prolongated to the fine
  // lattice (#fine nodes by 3), zero on the fine level's anchored nodes.
  RowMatrixX3d solve_increment(const RowMatrixX3d& targets, int iterations,
                               const std::vector<uint8_t>& fine_anchored);

 private:
  struct Level;
  const Lattice* fine_ = nullptr;
  std::vector<Level> levels_;  // levels_[k] is level k+1 (cells 2^(k+1) times larger)
};

}  // namespace larap
