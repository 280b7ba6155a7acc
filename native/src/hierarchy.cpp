#include "hierarchy.h"

#include "backend.h"
#include "handle_system.h"
#include "junction_braces.h"
#include "stencil.h"
#include "warm_start.h"

namespace larap {

struct Hierarchy::Level {
  Lattice lattice;
  std::unique_ptr<Backend> backend;
  // Prolongation: every node of the next finer level as a trilinear combination of this level's
  // nodes (the corners of the coarse cell that holds it).
  std::vector<std::array<int32_t, 8>> prolong_ids;
  std::vector<std::array<double, 8>> prolong_w;
  std::vector<std::array<int32_t, 3>> braces;  // the level's junction braces (junction_braces.h)
  std::vector<uint8_t> anchored;  // empty until handles are set
  std::vector<std::array<int32_t, 2>> group_components;  // (group, component) of the handles' rows

  // The finer level's displacement for an increment `delta` of this level, zero where
  // `finer_anchored` holds.
  RowMatrixX3d prolong(const RowMatrixX3d& delta, const std::vector<uint8_t>& finer_anchored) const {
    const int64_t nf = static_cast<int64_t>(prolong_ids.size());
    RowMatrixX3d out = RowMatrixX3d::Zero(nf, 3);
    for (int64_t i = 0; i < nf; ++i) {
      if (!finer_anchored.empty() && finer_anchored[i]) continue;
      for (int q = 0; q < 8; ++q) out.row(i) += prolong_w[i][q] * delta.row(prolong_ids[i][q]);
    }
    return out;
  }
};

Hierarchy::Hierarchy() = default;
Hierarchy::~Hierarchy() = default;
int Hierarchy::size() const { return static_cast<int>(levels_.size()); }
Hierarchy::Hierarchy(Hierarchy&&) noexcept = default;
Hierarchy& Hierarchy::operator=(Hierarchy&&) noexcept = default;

Hierarchy::Hierarchy(const Lattice& fine, const RowMatrixX3d& vertices, int levels, double brace) : brace_(brace) {
  levels_.reserve(size_t(std::max(levels - 1, 0)));  // `finer` points into levels_: no reallocation
  const Lattice* finer = &fine;
  for (int k = 1; k < levels; ++k) {
    if (finer->num_cells() <= 1) break;
    levels_.emplace_back();
    Level& lv = levels_.back();
    std::vector<int32_t> parent_copy;
    lv.lattice = finer->coarsened(&parent_copy);
    // Every real node of the finer level through the coarse copy of a finer cell copy that has it
    // as a corner (any one: copies sharing a node share the corners that interpolate it). Shell
    // nodes of the fine level get no entry; the backend refills them from the real ones.
    const int64_t nf = finer->num_nodes();
    lv.prolong_ids.assign(size_t(nf), {});
    lv.prolong_w.assign(size_t(nf), {});
    std::vector<uint8_t> done(static_cast<size_t>(nf), 0);
    for (int64_t c = 0; c < finer->num_cells(); ++c) {
      const Eigen::Vector3i parent = finer->cell_coords[c] / 2;
      const int32_t pc = parent_copy[c];
      for (int corner = 0; corner < 8; ++corner) {
        const int32_t i = finer->cell_nodes[c][corner];
        if (done[i]) continue;
        done[i] = 1;
        const Eigen::Vector3d f = 0.5 * (finer->node_coords[i] - 2 * parent).cast<double>();  // in [0,1]
        double w[8];
        trilinear_weights(f.x(), f.y(), f.z(), w);
        for (int q = 0; q < 8; ++q) {
          lv.prolong_ids[i][q] = lv.lattice.cell_nodes[pc][q];
          lv.prolong_w[i][q] = w[q];
        }
      }
    }
    if (brace_ > 0.0) lv.braces = junction_braces(lv.lattice);
    lv.backend = make_cpu_backend(lv.lattice, vertices);
    finer = &lv.lattice;
  }
}

void Hierarchy::set_handles(const HandleSpec& spec, double gamma, double size,
                            const Eigen::Vector3d& origin) {
  const int64_t m = spec.rest.rows();
  for (auto& lv : levels_) {
    lv.anchored.clear();
    if (m == 0) continue;
    std::vector<int32_t> cells(static_cast<size_t>(m));
    for (int64_t j = 0; j < m; ++j) cells[j] = lv.lattice.vertex_cell[spec.vertices[j]];
    const Binding hb = bind_points(lv.lattice, spec.rest, cells, WeightKind::Trilinear);
    std::vector<int32_t> ids(size_t(m) * 8);
    std::vector<double> w(ids.size());
    for (int64_t j = 0; j < m; ++j) hb.weights_of(lv.lattice, j, &ids[j * 8], &w[j * 8]);
    HandleSystem hs = make_handle_system(lv.lattice, 8, std::move(ids), std::move(w), spec, gamma, lv.braces, brace_,
                                         size, origin);
    lv.anchored = hs.anchored;
    lv.group_components = group_components(hs);
    lv.backend->set_handles(hs);
  }
}

void Hierarchy::reset() {
  for (auto& lv : levels_) lv.backend->set_pose(lv.lattice.rest);
}

std::vector<RowMatrixX3d> Hierarchy::poses() const {
  std::vector<RowMatrixX3d> out(levels_.size());
  for (size_t l = 0; l < levels_.size(); ++l) levels_[l].backend->get_pose(out[l]);
  return out;
}

void Hierarchy::set_poses(const std::vector<RowMatrixX3d>& poses) {
  for (size_t l = 0; l < levels_.size(); ++l) levels_[l].backend->set_pose(poses[l]);
}

int64_t Hierarchy::num_nodes(int level) const { return levels_[size_t(level)].lattice.num_nodes(); }

RowMatrixX3d Hierarchy::solve_increment(const HandleTargets& targets, int iterations,
                                        const std::vector<uint8_t>& fine_anchored, double still,
                                        const std::vector<uint8_t>& held_groups) {
  SolveStats scratch;
  RowMatrixX3d delta;  // increment of the level just solved, in its nodes
  for (int l = size() - 1; l >= 0; --l) {
    Level& lv = levels_[l];
    lv.backend->set_targets(targets);
    warm_start(*lv.backend, still, scratch,
               held_components(lv.group_components, held_groups, lv.lattice.num_components));
    RowMatrixX3d start;
    lv.backend->get_pose(start);
    if (l + 1 < size()) lv.backend->set_pose(start + levels_[l + 1].prolong(delta, lv.anchored));
    lv.backend->iterate(std::max(iterations, 1), scratch);
    RowMatrixX3d after;
    lv.backend->get_pose(after);
    delta = after - start;
  }
  return levels_[0].prolong(delta, fine_anchored);
}

}  // namespace larap
