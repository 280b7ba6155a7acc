// The CUDA backend, host side: the class CudaBackend (backend.h's Backend on the device). Internal
// to native/cuda (no public header includes it; it includes CUDA's). Its methods, one file per
// concept: construction, options and the factory (cuda_backend.cpp), the lattice system per
// handle set (cuda_system.cpp), the per-pose handle work (cuda_handles_host.cpp), the flip-flop
// loop with the energy and the pose (cuda_iterate.cpp), the transfer and its copy back into the
// caller's array (cuda_copy_back.cpp). Around it: device memory and errors (device_memory.h),
// options (cuda_options.h), the multigrid set-up (multigrid.h), the kernels (flip_flop.h,
// handles.h, solvers.h, transfer.h). Design and figures: docs/cuda.md, docs/results-gpu.md.
#pragma once
#include <cuda_runtime.h>

#include <Eigen/Dense>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "backend.h"
#include "cuda_options.h"
#include "device_memory.h"
#include "handles.h"
#include "multigrid.h"
#include "system.h"

namespace larap {

class CudaBackend final : public Backend {
 public:
  CudaBackend(const Lattice& lattice, const RowMatrixX3d& vertices);
  ~CudaBackend() override;

  std::string name() const override { return "cuda"; }

  // The options (cuda_options.h, from the environment) at construction and at every
  // set_handles, so that a benchmark can switch them without rebuilding the lattice.
  void configure();

  // The lattice system per handle set (cuda_system.cpp).
  void set_handles(const HandleSystem& hs) override;
  // The handle nodes (q_i > 0) by lattice component, in chunks of at most one block, for the
  // moments' reduction (handles.h).
  void upload_moment_chunks(const HandleSystem& hs);
  void upload_multigrid(const cuda::Multigrid& mg);

  // The pose on the device (cuda_iterate.cpp).
  // The real rows of `nodes` (#N by 3); the shell follows them (as the CPU's fill_shell).
  void set_pose(const RowMatrixX3d& nodes) override;
  void get_pose(RowMatrixX3d& nodes) const override;

  // The per-pose handle work (cuda_handles_host.cpp).
  // H and K of a pose. Group maps: G maps uploaded, H formed on the device from the per-node
  // entries, K from the group moments on the host (O(groups x components)). Row targets: H and
  // K on the host (O(m)), H uploaded.
  void set_targets(const HandleTargets& targets) override;
  // Per lattice component: a device reduction over the handle nodes, O(components) downloaded.
  void moments(std::vector<ComponentMoments>& now, std::vector<ComponentMoments>& rest) override;
  // Per lattice component x -> R x + t (centred frame, as the moments), one kernel.
  void apply_rigid(const std::vector<ComponentMotion>& motions, bool from_rest) override;

  // The flip-flop loop and the energy (cuda_iterate.cpp).
  void iterate(int iterations, SolveStats& stats) override;
  double energy() override;

  // The transfer (cuda_copy_back.cpp).
  void transfer(const Binding& b, double* out, SolveStats& stats) override;
  // The transfer into the device output buffer, left there (no copy to the host).
  const float* transfer_on_device(const Binding& b, SolveStats& stats) override;
  void transfer(const Binding& b, float* out, SolveStats& stats) override;

 private:
  // Slot of j among i's lattice neighbours (-x,+x,-y,+y,-z,+z), or -1 if not a unit step.
  static int nbr_slot(const Eigen::Vector3i& ci, const Eigen::Vector3i& cj) {
    const Eigen::Vector3i d = cj - ci;
    if (d.cwiseAbs().sum() != 1) return -1;
    for (int a = 0; a < 3; ++a)
      if (d[a] != 0) return 2 * a + (d[a] > 0 ? 1 : 0);
    return -1;
  }
  // The stencil shell's rows of x from the real rows (after every change of the real rows).
  void fill_shell();
  // One pose's moments per component from kMomentValues doubles each (handles.h's order).
  void unpack_moments(const double* h, std::vector<ComponentMoments>& out) const;

  float4 to_f4(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d c = p - origin_;
    return make_float4(float(c.x()), float(c.y()), float(c.z()), 0.f);
  }
  Eigen::Vector3d from_f4(const float4& p) const { return Eigen::Vector3d(p.x, p.y, p.z) + origin_; }

  // The graph holds the buffer's address: a new buffer needs a new graph.
  void set_energy_buffer(size_t n);

  // Scaled energy from the device's two sums of one flip-flop: ARAP + anchors, and the handle
  // term without K (c.(M c - 2 H)), as the CPU backend forms it.
  double total_energy(double arap, double handles) const;

  // Moves the device frame to `o` (the handle system's origin), keeping the pose.
  void recentre(const Eigen::Vector3d& o);

  void launch_solver();
  // Blocks for the fused kernel (0: no cooperative launch possible).
  int fused_blocks();
  void flip_flop();
  void build_graph();

  struct DevBinding {
    const Binding* key = nullptr;
    int64_t nv = -1;
    cuda::DeviceBuffer<int> table;
    cuda::DeviceBuffer<float4> packed;  // (base id as int bits, 3 fractions)
  };

  DevBinding& device_binding(const Binding& b);
  const float* device_vertices(float*);
  const double* device_vertices(double*);
  float* device_out(float*, size_t n) { return outf_.reserve(n); }
  double* device_out(double*, size_t n) { return outd_.reserve(n); }

  template <typename T>
  void launch_transfer(const Binding& b, DevBinding& d, int64_t v0, int64_t v1, const T* V, T* out);
  template <typename T>
  void transfer_any(const Binding& b, T* out, SolveStats& stats);
  // The transfer of vertices [0, nv) into the caller's host array `out`, as opt_.copy says
  // (cuda_options.h; measured in docs/results-gpu.md).
  template <typename T>
  void copy_back(const Binding& b, DevBinding& d, int64_t nv, const T* V, T* dout, T* out);

  // One JSON line to opt_.phases_path: the fused kernel's mean clock cycles per grid-wide phase of
  // a flip-flop over one iterate, from its clock64() stamps (cuda_iterate.cpp).
  void write_phases(const std::vector<double>& cycles, int flip_flops);
  // One JSON line to opt_.profile_path (cuda_backend.cpp).
  void write_profile(const char* what, int iterations,
                     std::initializer_list<std::pair<const char*, double>> kv);

  const Lattice& lat_;
  const RowMatrixX3d& V_;
  Eigen::Vector3d origin_;
  int n_ = 0;      // real nodes: the unknowns
  int n_all_ = 0;  // real + stencil shell nodes
  std::vector<int> nbr_host_;  // 6 * n_: the neighbour slots (system.h)
  cuda::CudaOptions opt_;
  int inner_ = 8;      // inner solver iterations per flip-flop (opt_.inner, or automatic)
  int coop_max_ = -1;  // most co-resident blocks of the fused kernel (-1: not asked yet)
  double lam_min_ = 0.0, lam_max_ = 2.0;
  bool ready_ = false;
  bool targets_set_ = false;
  HandleSystem hs_;
  std::vector<double> K_;  // K of the current targets, per lattice component
  double K_total_ = 0.0;
  RowMatrixX3d H_rows_;    // row targets: H on the host
  std::vector<float4> h_rows_;
  std::vector<double> h_maps_;
  std::vector<float> h_motions_;
  std::vector<int> mc_nodes_host_, mc_chunk_off_host_, mc_comp_off_host_;
  cuda::GroupEntries entries_;
  cuda::MomentChunks moment_chunks_;

  cuda::Stream stream_;  // first: destroyed after every buffer's last use
  cuda::System sys_;
  cuda::DeviceBuffer<float4> rest_, x_, p_, r_[2], w_[2], s_[2], xtmp_, disp_, h_;
  cuda::DeviceBuffer<double> hd_, q_, m_val_, e_q_, e_P_, maps_, mom_partial_, mom_out_;
  cuda::DeviceBuffer<double> mh_val_;
  cuda::DeviceBuffer<int> mh_off_, mh_col_;
  cuda::DeviceBuffer<int> comp_, m_off_, m_col_, e_off_, e_group_, mc_nodes_, mc_chunk_off_, mc_comp_off_;
  cuda::DeviceBuffer<float> motions_;
  cuda::PinnedBuffer<double> h_moments_;
  cuda::DeviceBuffer<int> agg_, nbr_, rem_off_, rem_col_, ap_col_, ap_off_, ap_rcol_;
  cuda::DeviceBuffer<float> a_diag_, a_nb_, rem_val_, ap_val_, ap_rval_;
  cuda::DeviceBuffer<float> ainv_;
  cuda::DeviceBuffer<float4> rc_, zc_, rc2_, zc2_, sm_;
  cuda::DeviceBuffer<int> agg2_, c_off_, c_col_;
  cuda::DeviceBuffer<float> c_val_, c_minv_;
  cuda::DeviceBuffer<int> nbx_off_, nbx_, shell_off_, shell_ids_, a_off_, a_col_, iter_;
  cuda::DeviceBuffer<float> nbw_, nbxw_;  // edge weights of the slots and extras (weighted lattices)
  cuda::DeviceBuffer<float> shell_w_;
  cuda::DeviceBuffer<int> cell_nodes_, nc_off_, nc_cell_;  // cell copies (system.h)
  cuda::DeviceBuffer<float> cell_w_;
  cuda::DeviceBuffer<int> cp_off_, cp_trunk_;  // branch couplings (system.h)
  cuda::DeviceBuffer<float> cp_w_;
  cuda::DeviceBuffer<float4> nc_s_;
  cuda::DeviceBuffer<float> a_val_, minv_, coef_;
  cuda::DeviceBuffer<float4> rot_;
  cuda::DeviceBuffer<uint8_t> anch_;
  cuda::DeviceBuffer<double> dots_, energy_;
  cuda::DeviceBuffer<unsigned> counters_;
  cuda::PinnedBuffer<double> h_energy_;
  mutable cuda::PinnedBuffer<float4> h_pose_;  // set_pose / get_pose: page-locked, one copy each way
  cuda::DeviceBuffer<long long> stamps_;  // LARAP_CUDA_PHASES only
  cuda::PinnedBuffer<char> staging_;
  DevBinding bind_[2];
  cuda::DeviceBuffer<float> vf_;
  cuda::DeviceBuffer<double> vd_;
  int64_t vf_n_ = -1, vd_n_ = -1;
  cuda::DeviceBuffer<float> outf_;
  cuda::DeviceBuffer<double> outd_;
  cuda::Event ev_[4];
  std::vector<std::unique_ptr<cuda::Event>> chunk_ev_;
  cuda::GraphExec graph_;  // last: destroyed first
};

}  // namespace larap
