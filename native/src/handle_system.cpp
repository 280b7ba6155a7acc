#include "handle_system.h"

#include <algorithm>

namespace larap {

HandleSystem make_handle_system(const Lattice& lat, int stencil, std::vector<int32_t> ids,
                                std::vector<double> weights, double gamma, double size) {
  HandleSystem hs;
  hs.stencil = stencil;
  hs.m = static_cast<int64_t>(ids.size()) / stencil;
  hs.ids = std::move(ids);
  hs.weights = std::move(weights);

  const double m = double(std::max<int64_t>(hs.m, 1));
  const double directed = std::max<double>(1.0, 2.0 * double(lat.edges.size()));
  const double s = size, h = lat.h;
  hs.gamma_eff = gamma * m * s * s / (h * h * directed);
  hs.energy_scale = 1.0 / (m * s * s);

  // Components without a handle stay at rest (their system would be singular otherwise).
  std::vector<uint8_t> has_handle(size_t(lat.num_components), 0);
  for (int64_t j = 0; j < hs.m; ++j)
    for (int k = 0; k < hs.stencil; ++k)
      if (hs.weights[j * hs.stencil + k] != 0.0) has_handle[lat.component[hs.ids[j * hs.stencil + k]]] = 1;
  const int64_t nn = lat.num_nodes();
  hs.anchored.resize(size_t(nn));
  for (int64_t i = 0; i < nn; ++i) hs.anchored[i] = has_handle[lat.component[i]] ? 0 : 1;
  hs.anchor_weight = 2.0 * hs.gamma_eff;
  return hs;
}

std::vector<Eigen::Triplet<double>> arap_triplets(const Lattice& lat, const HandleSystem& hs) {
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(lat.edges.size() * 4 + size_t(lat.num_nodes()));
  const double g2 = 2.0 * hs.gamma_eff;
  for (const auto& e : lat.edges) {
    trip.emplace_back(e[0], e[0], g2);
    trip.emplace_back(e[1], e[1], g2);
    trip.emplace_back(e[0], e[1], -g2);
    trip.emplace_back(e[1], e[0], -g2);
  }
  for (int64_t i = 0; i < lat.num_nodes(); ++i)
    if (hs.anchored[i]) trip.emplace_back(int(i), int(i), hs.anchor_weight);
  return trip;
}

std::vector<Eigen::Triplet<double>> handle_triplets(const HandleSystem& hs) {
  std::vector<Eigen::Triplet<double>> bt;
  bt.reserve(size_t(hs.m) * hs.stencil);
  for (int64_t j = 0; j < hs.m; ++j)
    for (int k = 0; k < hs.stencil; ++k)
      bt.emplace_back(int(j), hs.ids[j * hs.stencil + k], hs.weights[j * hs.stencil + k]);
  return bt;
}

}  // namespace larap
