#include "handle_system.h"

#include <larap/errors.h>

#include <algorithm>
#include <array>
#include <limits>

#include "carried_parts.h"
#include "parallel.h"

namespace larap {

HandleSystem make_handle_system(const Lattice& lat, int stencil, std::vector<int32_t> ids,
                                std::vector<double> weights, const HandleSpec& spec, double gamma,
                                const std::vector<std::array<int32_t, 3>>& braces, double brace,
                                double size, const Eigen::Vector3d& origin) {
  const std::vector<double>& omega = spec.omega;
  const std::vector<double>& group_weights = spec.group_weights;
  const RowMatrixX3d& rest = spec.rest;
  HandleSystem hs;
  hs.stencil = stencil;
  hs.m = static_cast<int64_t>(ids.size()) / stencil;
  hs.ids = std::move(ids);
  hs.weights = std::move(weights);
  hs.group_offsets = spec.group_offsets;
  hs.origin = origin;
  hs.num_components = lat.num_components;
  const int64_t G = hs.num_groups(), m = hs.m, nn = lat.num_nodes();

  // Row weights: each group pulls w_g / G, spread over its rows by omega.
  hs.alpha.assign(size_t(m), 0.0);
  for (int64_t g = 0; g < G; ++g) {
    const int64_t b = hs.group_offsets[g], e = hs.group_offsets[g + 1];
    double total = 0.0;
    for (int64_t j = b; j < e; ++j) total += omega.empty() ? 1.0 : omega[j];
    const double wg = group_weights.empty() ? 1.0 : group_weights[g];
    if (!(total > 0.0) || !(wg > 0.0)) continue;  // a group that pulls nowhere
    for (int64_t j = b; j < e; ++j) hs.alpha[j] = wg / double(G) * (omega.empty() ? 1.0 : omega[j]) / total;
  }

  // gamma is per term of the energy, one (cell copy, edge) pair weighing cell_weight: twice the
  // edge weights' sum is the terms' (12 per whole cell). A branch coupling's weight is in the edge
  // weights too (each of its trunk copy's 12 edges gains half of it) but is not material: it is
  // left out, so that splitting per branch does not soften the rest of the lattice against the
  // handles, the anchors, the glue and the braces.
  double weight = 0.0;
  for (double w : lat.edge_weight) weight += w;
  for (const Coupling& k : lat.couplings) weight -= 6.0 * k.weight;
  weight = std::max(weight, 0.0);
  const double directed = std::max<double>(1.0, 2.0 * weight);
  const double s = size, h = lat.h;
  hs.gamma_eff = gamma * s * s / (h * h * directed);
  // The anchors and the glue pull per unit of the mean edge weight (2 inside a plain lattice), so
  // that they stand to the lattice's stiffness as they did with one weight per edge, where kGlue
  // was measured (carried_parts.h).
  const double mean_edge = lat.edges.empty() ? 1.0 : weight / double(lat.edges.size());
  hs.energy_scale = 1.0 / (s * s);

  // The component of each row; components without a pulling row are carried by a handled one
  // (carried_parts.h) or else stay at rest (their system would be singular otherwise).
  hs.row_component.assign(size_t(m), 0);
  std::vector<uint8_t> has_handle(size_t(lat.num_components), 0);
  for (int64_t j = 0; j < m; ++j) {
    int32_t comp = -1;
    for (int k = 0; k < stencil; ++k)
      if (hs.weights[j * stencil + k] != 0.0) comp = lat.component[hs.ids[j * stencil + k]];
    if (comp < 0) comp = lat.component[hs.ids[j * stencil]];
    hs.row_component[j] = comp;
    if (hs.alpha[j] > 0.0) has_handle[comp] = 1;
  }
  CarriedParts carried = carried_parts(lat, has_handle);
  hs.anchored = std::move(carried.anchored);
  hs.node_component = std::move(carried.node_component);
  hs.glue = std::move(carried.glue);
  hs.anchor_weight = 2.0 * hs.gamma_eff * mean_edge;
  hs.glue_weight = kGlue * hs.gamma_eff * mean_edge;
  if (brace > 0.0 && !braces.empty()) {
    hs.braces = braces;
    hs.brace_weight = brace * hs.gamma_eff * mean_edge;
  }

  // q = B^T alpha; per (node, group) q_g[i] and P_g[i], accumulated group by group in a dense
  // scratch row over the nodes the group touches, then ordered by node (counting sort); per
  // (group, component) the moments.
  hs.q.assign(size_t(nn), 0.0);
  struct Entry {
    int32_t node, group;
    double q, P[3];
  };
  std::vector<Entry> entries;
  std::vector<int32_t> slot(size_t(nn), -1);  // entry of node i for the current group
  std::vector<int64_t> moment_of(size_t(lat.num_components), -1);
  for (int64_t g = 0; g < G; ++g) {
    const size_t first = entries.size();
    std::fill(moment_of.begin(), moment_of.end(), -1);
    for (int64_t j = hs.group_offsets[g]; j < hs.group_offsets[g + 1]; ++j) {
      const double a = hs.alpha[j];
      if (a == 0.0) continue;
      const Eigen::Vector3d v = rest.row(j).transpose() - origin;
      for (int k = 0; k < stencil; ++k) {
        const double bw = hs.weights[j * stencil + k];
        if (bw == 0.0) continue;
        const int32_t i = hs.ids[j * stencil + k];
        hs.q[i] += a * bw;
        if (slot[i] < 0 || size_t(slot[i]) < first) {
          slot[i] = int32_t(entries.size());
          entries.push_back({i, int32_t(g), 0.0, {0.0, 0.0, 0.0}});
        }
        Entry& e = entries[size_t(slot[i])];
        e.q += a * bw;
        for (int c = 0; c < 3; ++c) e.P[c] += a * bw * v[c];
      }
      const int32_t comp = hs.row_component[j];
      if (moment_of[comp] < 0) {
        moment_of[comp] = int64_t(hs.moments.size());
        hs.moments.emplace_back();
        hs.moments.back().group = int32_t(g);
        hs.moments.back().component = comp;
      }
      auto& mo = hs.moments[size_t(moment_of[comp])];
      mo.s0 += a;
      mo.s1 += a * v;
      mo.s2 += a * v * v.transpose();
    }
  }
  if (entries.size() > size_t(std::numeric_limits<int32_t>::max()))
    throw OutOfMemory("the handle groups touch too many lattice nodes");
  hs.node_offsets.assign(size_t(nn + 1), 0);
  for (const Entry& e : entries) ++hs.node_offsets[e.node + 1];
  for (int64_t i = 0; i < nn; ++i) hs.node_offsets[i + 1] += hs.node_offsets[i];
  hs.entry_group.resize(entries.size());
  hs.entry_q.resize(entries.size());
  hs.entry_P.resize(3 * entries.size());
  std::vector<int32_t> fill(hs.node_offsets.begin(), hs.node_offsets.end() - 1);
  for (const Entry& e : entries) {  // groups in order within each node
    const size_t k = size_t(fill[e.node]++);
    hs.entry_group[k] = e.group;
    hs.entry_q[k] = e.q;
    for (int c = 0; c < 3; ++c) hs.entry_P[3 * k + c] = e.P[c];
  }
  return hs;
}

void handle_rhs(const HandleSystem& hs, const HandleTargets& targets, RowMatrixX3d& H,
                std::vector<double>& K) {
  const int64_t nn = static_cast<int64_t>(hs.q.size());
  H.setZero(nn, 3);
  K.assign(size_t(hs.num_components), 0.0);
  const Eigen::RowVector3d o = hs.origin.transpose();
  if (targets.rows) {
    const Eigen::Map<const RowMatrixX3d> T(targets.rows, hs.m, 3);
    const int s = hs.stencil;
    for (int64_t j = 0; j < hs.m; ++j) {  // serial: rows of several handles share nodes
      const double a = hs.alpha[j];
      if (a == 0.0) continue;
      const Eigen::RowVector3d t = T.row(j) - o;
      for (int k = 0; k < s; ++k) H.row(hs.ids[j * s + k]) += a * hs.weights[j * s + k] * t;
      K[hs.row_component[j]] += a * t.squaredNorm();
    }
    return;
  }
  if (!targets.groups) throw StateError("handle targets: neither rows nor group maps");
  const GroupMaps m = group_maps(hs, targets.groups);
  const auto& A = m.A;
  const auto& b = m.b;
  parallel_for(nn, [&](int64_t i) {
    Eigen::Vector3d h = Eigen::Vector3d::Zero();
    for (int32_t k = hs.node_offsets[i]; k < hs.node_offsets[i + 1]; ++k) {
      const int32_t g = hs.entry_group[k];
      const Eigen::Vector3d P(&hs.entry_P[3 * size_t(k)]);
      h += A[g] * P + hs.entry_q[k] * b[g];
    }
    H.row(i) = h.transpose();
  }, 2048);
  group_constants(hs, m, K);
}

GroupMaps group_maps(const HandleSystem& hs, const Affine34* maps) {
  const int64_t G = hs.num_groups();
  GroupMaps m;
  m.A.resize(static_cast<size_t>(G));
  m.b.resize(static_cast<size_t>(G));
  for (int64_t g = 0; g < G; ++g) {
    m.A[g] = maps[g].leftCols<3>();
    m.b[g] = m.A[g] * hs.origin + maps[g].col(3) - hs.origin;
  }
  return m;
}

void group_constants(const HandleSystem& hs, const GroupMaps& maps, std::vector<double>& K) {
  K.assign(size_t(hs.num_components), 0.0);
  for (const auto& mo : hs.moments) {
    const Eigen::Matrix3d& Ag = maps.A[mo.group];
    const Eigen::Vector3d& bg = maps.b[mo.group];
    K[mo.component] += (Ag * mo.s2 * Ag.transpose()).trace() + 2.0 * bg.dot(Ag * mo.s1) + mo.s0 * bg.squaredNorm();
  }
}

Eigen::SparseMatrix<double> handle_matrix(const HandleSystem& hs, int64_t num_nodes) {
  std::vector<Eigen::Triplet<double>> bt, abt;
  const int s = hs.stencil;
  bt.reserve(size_t(hs.m) * s);
  abt.reserve(size_t(hs.m) * s);
  for (int64_t j = 0; j < hs.m; ++j) {
    if (hs.alpha[j] == 0.0) continue;
    for (int k = 0; k < s; ++k) {
      bt.emplace_back(int(j), hs.ids[j * s + k], hs.weights[j * s + k]);
      abt.emplace_back(int(j), hs.ids[j * s + k], hs.alpha[j] * hs.weights[j * s + k]);
    }
  }
  Eigen::SparseMatrix<double> B(hs.m, num_nodes), AB(hs.m, num_nodes);
  B.setFromTriplets(bt.begin(), bt.end());
  AB.setFromTriplets(abt.begin(), abt.end());
  Eigen::SparseMatrix<double> M = Eigen::SparseMatrix<double>(B.transpose()) * AB;
  M.makeCompressed();
  return M;
}

std::vector<std::array<int32_t, 2>> group_components(const HandleSystem& hs) {
  std::vector<std::array<int32_t, 2>> out;
  out.reserve(hs.moments.size());
  for (const auto& mo : hs.moments) out.push_back({mo.group, mo.component});
  return out;
}

Eigen::SparseMatrix<double> tie_matrix(const HandleSystem& hs, int64_t num_nodes) {
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(4 * hs.glue.size() + 9 * hs.braces.size());
  const double mu = hs.glue_weight;
  for (const auto& [a, b] : hs.glue) {
    trip.emplace_back(a, a, mu);
    trip.emplace_back(b, b, mu);
    trip.emplace_back(a, b, -mu);
    trip.emplace_back(b, a, -mu);
  }
  const double beta = hs.brace_weight;
  for (const auto& s : hs.braces) {  // beta s s^T, s = (1, -2, 1) on (a, b, c)
    constexpr double coef[3] = {1.0, -2.0, 1.0};
    for (int u = 0; u < 3; ++u)
      for (int v = 0; v < 3; ++v) trip.emplace_back(s[u], s[v], beta * coef[u] * coef[v]);
  }
  Eigen::SparseMatrix<double> G(num_nodes, num_nodes);
  G.setFromTriplets(trip.begin(), trip.end());
  return G;
}

std::vector<Eigen::Triplet<double>> arap_triplets(const Lattice& lat, const HandleSystem& hs) {
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(lat.edges.size() * 4 + size_t(lat.num_nodes()));
  const double g2 = 2.0 * hs.gamma_eff;
  for (size_t k = 0; k < lat.edges.size(); ++k) {
    const auto& e = lat.edges[k];
    const double w = g2 * lat.edge_weight[k];
    trip.emplace_back(e[0], e[0], w);
    trip.emplace_back(e[1], e[1], w);
    trip.emplace_back(e[0], e[1], -w);
    trip.emplace_back(e[1], e[0], -w);
  }
  for (int64_t i = 0; i < lat.num_real_nodes(); ++i)  // the shell is not in the system
    if (hs.anchored[i]) trip.emplace_back(int(i), int(i), hs.anchor_weight);
  return trip;
}

}  // namespace larap
