#pragma once
/// \file mpm_solver.h
/// The explicit Material Point Method solver: one substep is
///
///   bin_particles   particle indices sorted by grid block (blocks.h)
///   particles_to_grid  per bin: compute_stress K_p = -dt V_p^0 tau(F_p) (per material; snow
///                   hardening here), then mass, momentum, affine momentum, stress impulse ->
///                   nodes, block by block in 2^Dim colour phases (race-free, same sums on any
///                   thread count)
///   update_grid     v_i = p_i / m_i + dt g; walls and colliders
///   grid_to_particles  v_p, C_p, F_p <- (I + dt grad v) F_p (or J_p), x_p += dt v_p
///   return_mapping  plastic projection of F_p (per plastic material; Drucker-Prager sand on
///                   Hencky elasticity instead at the start of the next particles_to_grid, where
///                   the projection's SVD also gives the stress: explicit integrator only)
///   (solver.sleep) blocks of particles at rest skip the stress, the scatter (their last
///                   contribution is reused), the gather and the projection until something moves
///   check_health    non-finite state, CFL violation, particle outside the domain -> SimulationError
///
/// Split over processes (a Communicator with more than one rank, communicator.h; `mpirun -np N
/// slurry run`): the lattice of grid blocks is cut into boxes, one per rank (slabs, pencils or
/// boxes: process_grid picks the processes per axis whose cuts cross the fewest block faces), with
/// borders that follow the particle counts at every frame (BoxSplit, balanced_cuts). Each substep
/// a rank bins and scatters its own particles only; the grid nodes near a border, which the
/// particles of blocks on both sides reach, are then summed again from every rank's
/// contributions (the grid halo: each rank sends its border blocks' shared patch nodes to the
/// ranks whose boxes touch its own, distribution.h). Each rank updates the grid, gathers and
/// projects its own particles and hands particles that crossed a border to their new owner; the
/// time step and the health check are global. Bins are ordered by persistent id and the halo's nodes
/// are summed in the colour order of the scatter, so every node a rank reads holds the same sum as
/// in one process and frames are bitwise those of one process.
/// Frames and checkpoints are gathered to every rank in one piece (rank 0 writes them), or with
/// output.per_rank written by each rank for its own particles (own_frame, save_own_state); a
/// checkpoint, whole or in parts (load_state_parts), resumes on any number of ranks. The implicit update and solver.sleep run on one
/// rank only (refused with more).
///
/// following Stomakhin et al. 2013 ("A material point method for snow simulation") for the
/// explicit MPM step, Jiang et al. 2015 (APIC) and Hu et al. 2018 (MLS-MPM) for the transfers.
/// The time step is the smallest of solver.max_dt, cfl dx / max |v_p| and
/// elastic_cfl dx / max_materials sqrt((lambda + 2 mu) / rho) (sqrt(K / rho) for fluids).
///
/// With solver.integrator "implicit", update_grid is replaced by the linearly implicit
/// backward-Euler solve of engine/src/mpm/implicit_update.h ((M + dt^2 H) v = M v*, matrix-free
/// Jacobi-preconditioned CG; Stomakhin et al. 2013, sec. 9), and the time step ignores the
/// elastic limit (only max_dt and the CFL limit remain).
///
/// Two API levels: `run_scene` (run.h) for the common case, and this class for control.
#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "slurry/engine/geometry/colliders.h"
#include "slurry/engine/communicator.h"
#include "slurry/engine/mpm/material.h"
#include "slurry/engine/mpm/particles.h"
#include "slurry/engine/frame.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/stats.h"
#include "slurry/engine/substeps.h"
#include "slurry/transfer/blocks.h"
#include "slurry/transfer/grid.h"
#include "slurry/transfer/sparse_grid.h"
#include "slurry/transfer/transfers.h"

namespace slurry {
namespace detail {
class StateReader;  // engine/src/state_io.h
}

/// Wall-clock seconds spent in each phase of the MPM substep since the simulation started.
struct PhaseTimes {
  double binning = 0;     ///< bin_particles
  double reorder = 0;     ///< the periodic re-sort of particle storage into bin order
  double p2g = 0;         ///< particles_to_grid (grid block allocation and the stress update included)
  double grid = 0;        ///< update_grid
  double g2p = 0;         ///< grid_to_particles
  double plasticity = 0;  ///< return_mapping
};

template <class T, int Dim>
class ImplicitUpdate;
template <class T, int Dim>
struct GridBoundaries;

/// Conjugate-gradient statistics of the implicit grid update (all zero for "explicit").
struct CgStats {
  int last_iterations = 0;       ///< iterations of the last substep's solve
  double last_residual = 0;      ///< its relative residual
  std::int64_t solves = 0;       ///< substeps solved
  std::int64_t iterations = 0;   ///< iterations summed over all solves
  std::int64_t unconverged = 0;  ///< solves that hit solver.cg_max_iterations (or broke down)
};

template <class T, int Dim>
class MpmSolver final : public Solver {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using DenseGrid = transfer::DenseGrid<T, Dim>;
  using SparseGrid = transfer::SparseGrid<T, Dim>;

  /// Validates the scene and seeds its bodies with particles. With a communicator of more than
  /// one rank, this process keeps its slab's particles (every rank must build the simulation
  /// from the same scene); SceneError if the scene asks for what a split run does not support.
  explicit MpmSolver(const Scene& scene, Communicator* communicator = nullptr);
  ~MpmSolver() override;

  /// The substep the stability limits allow now (not clipped to a frame boundary).
  T stable_dt() const;
  /// One substep of length dt. Throws SimulationError if the state becomes unhealthy.
  void step(T dt);

  double time() const override { return time_; }
  std::int64_t steps() const override { return steps_; }
  /// All ranks' particles in a split run.
  std::size_t particle_count() const override;
  /// Summed over the ranks in a split run (collective there).
  std::size_t bytes() const override;
  std::int64_t advance_to(double t_end) override;
  Frame frame(const std::vector<std::string>& attributes) const override;
  Frame own_frame(const std::vector<std::string>& attributes) const override;

  /// This process's particles (in a split run: its slab's, between substeps).
  Particles<T, Dim>& particles() { return particles_; }
  const Particles<T, Dim>& particles() const { return particles_; }
  const Scene& scene() const { return scene_; }
  /// Largest particle speed after the last substep (m/s).
  T max_speed() const { return max_speed_; }
  /// Total kinetic energy sum_p m_p |v_p|^2 / 2.
  T kinetic_energy() const;
  /// Time spent per phase so far (for benchmarks and the cost of each setting).
  const PhaseTimes& phase_times() const { return phase_times_; }
  /// Bytes of grid nodes this rank has sent to its neighbours so far (the grid halo of a split
  /// run; 0 in one process), for the scaling figures of benchmarks/.
  std::uint64_t halo_bytes_sent() const;
  /// Total elastic energy sum_p V_p^0 psi(F_p) (zero for fluids).
  T elastic_energy() const;
  /// CG iterations of the last substep's implicit solve (0 for "explicit").
  int last_cg_iterations() const { return cg_.last_iterations; }
  const CgStats& cg_stats() const { return cg_; }
  /// Grid blocks whose particles sleep now (solver.sleep; 0 when off), and how many times a
  /// block fell asleep since the start.
  std::size_t sleeping_blocks() const;
  std::int64_t blocks_fallen_asleep() const;
  std::string solver_status() const override;
  RunStats take_stats() override;
  ParticleStorage particle_storage() const override;
  using Solver::save_state;
  void save_state(const StateSink& sink) const override;
  void load_state(std::string_view in, const std::string& what) override;
  void save_own_state(const StateSink& sink) const override;
  void load_state_parts(int parts, const std::function<std::string(int)>& part, const std::string& what) override;

 private:
  /// Particles are re-stored in bin order every this many substeps (between, they are reached
  /// through the bins' index list), so the transfers stream through memory.
  static constexpr std::int64_t kReorderInterval = 8;
  static constexpr std::uint32_t kStressChunk = 256;  // particles per stack batch of K_p (scatter_bin; 18 KB in 3D double)

  void seed_bodies();
  // The split over processes (null in one process): see the file comment.
  struct Split;
  template <int Order>
  IVec block_order(const Vec& x) const;
  /// The grid block a particle at x is binned to (clamped to the block lattice).
  IVec block_of(const Vec& x) const;
  /// `counts` plus the particles at positions x per block of the lattice (linear index, the last
  /// axis fastest).
  std::vector<double> block_counts(const std::vector<Vec>& x, std::vector<double> counts = {}) const;
  /// Whether a particle at x lies in this rank's box.
  bool owns(const Vec& x) const;
  /// Box borders balanced for the particle counts per block (this rank's, summed over the ranks
  /// level by level; or, `summed`, every rank's already), the per-rank extremes for the log, and
  /// this rank's peers; true if they moved.
  bool set_borders(const std::vector<double>& lattice, bool summed);
  /// The state of particles P (every process's, or this process's part of a split run:
  /// `part`); and the readers of its sections.
  void write_state(const Particles<T, Dim>& P, const StateSink& sink, bool part) const;
  void read_particles(detail::StateReader& r, Particles<T, Dim>& P) const;
  void read_scalars(detail::StateReader& r);
  /// Keeps this rank's particles of a full set (after seeding and after load_state).
  void split_particles();
  /// New box borders from the particle counts; particles move to their new owners.
  void rebalance();
  /// Hands the particles outside this rank's box to their owners: the peers after a substep
  /// (particles move less than a block), any rank after new borders.
  void migrate();
  template <int Order>
  void migrate_order();
  /// The owner of each neighbour of `block` (owners[o] for offset o, distribution.h; -1 outside
  /// the lattice).
  void neighbour_owners(const IVec& block, int* owners) const;
  /// The grid halo: which occupied blocks touch another rank's box (before P2G); their patches,
  /// kept during P2G (any thread, its own slot); after P2G, the shared nodes swapped with the
  /// peers and summed again in colour order.
  template <int Order>
  void prepare_halo();
  template <int Order>
  void keep_halo_patch(std::size_t group, const transfer::Patch<T, Dim, Order>& patch);
  template <int Order, class G>
  void exchange_halo(G& grid);
  /// Every rank's particles, on every rank or on rank 0 only (empty elsewhere).
  Particles<T, Dim> all_particles(bool on_every_rank) const;
  /// P's particles as a frame; particle p's values land in row rows[p] (P.id when null: one
  /// process holds every particle, and ids are 0 .. n - 1).
  Frame frame_of(const Particles<T, Dim>& P, const std::vector<std::string>& attributes,
                       const std::uint32_t* rows = nullptr) const;
  std::string diagnosis(T dt) const;
  template <class G>
  void step_on(G& grid, T dt);
  /// K[i - begin] = -dt V_p^0 tau(F_p) for the particles p = order()[i], i in [begin, end), of
  /// one material.
  void compute_stress(int material, std::uint32_t begin, std::uint32_t end, T dt, Mat* K) const;
  /// compute_stress() for a material whose return mapping runs in P2G (project_in_p2g_): first
  /// projects F_p (and its plastic state), the stress from the projection's SVD; adds the
  /// number of particles that yielded to `yielded`.
  void project_and_stress(int material, std::uint32_t begin, std::uint32_t end, T dt, Mat* K, std::int64_t& yielded);
  /// Scatters bin b's particles to `patch`, their stress computed just before in chunks of
  /// kStressChunk on the stack (no per-particle stress array: 36 bytes per particle in 3D float);
  /// `project`: apply the return mappings that run in P2G (not for a sleeping block's cache).
  template <int Order, transfer::Scheme S, class Patch>
  void scatter_bin(Patch& patch, const typename transfer::ParticleBins<Dim>::Bin& bin, T dt, bool project);
  void bin_particles();
  void reorder_particles();
  template <class G>
  void particles_to_grid(G& grid, T dt);
  template <class G>
  void update_grid(G& grid, T dt);
  template <class G>
  void grid_to_particles(G& grid, T dt);
  void update_grid_implicit(DenseGrid& grid, T dt);
  /// Walls (node index ranges) and colliders at time t, for both grid updates.
  GridBoundaries<T, Dim> grid_boundaries(T t) const;
  void return_mapping();
  bool fluid_wave_speeds();  // return_mapping's end: this rank's liquids' wave speeds at their J; false if no liquid
  [[noreturn]] void diagnose(T dt) const;
  // Sleeping material (solver.sleep, scene.h): which blocks sleep this substep and their cached
  // grid contributions (sleep_prepare, after binning); blocks whose nodes moved wake
  // (sleep_wake, after the grid update); calm blocks fall asleep (sleep_update, at the end).
  struct SleepState;
  void sleep_prepare();
  template <int Order, class G>
  void sleep_wake(G& grid);
  void sleep_update();

  template <int Order>
  void bin_particles_order();
  template <int Order, class G>
  void particles_to_grid_order(G& grid, T dt);
  template <int Order, class G>
  void grid_to_particles_order(G& grid, T dt);

  Scene scene_;
  std::vector<Material<T, Dim>> materials_;
  std::vector<Collider<T, Dim>> colliders_;
  Particles<T, Dim> particles_;
  std::vector<std::uint64_t> reorder_done_;  // one bit per particle, reorder_particles
  std::vector<Vec> x_before_;  // positions before the move, kept for thin colliders only
  std::vector<std::uint8_t> fluid_;  // per material: advances J instead of F
  std::vector<T> hardening_scratch_;  // per bin, snow only
  std::vector<std::pair<T, T>> fluid_J_scratch_;  // per bin, liquids only: smallest and largest J
  std::vector<std::int64_t> projected_scratch_;  // per bin: return mappings that yielded (P2G's, then return_mapping's)
  // Per material: its return mapping runs in P2G, just before its stress, instead of after G2P
  // (Drucker-Prager on Hencky StVK, explicit integrator): the projection's SVD gives the stress,
  // one 3x3 SVD per particle and substep instead of two. F_p between substeps is then the trial
  // F of G2P, projected at the start of the next substep (or when its block falls asleep).
  std::vector<std::uint8_t> project_in_p2g_;
  std::int64_t projected_ = 0;  // since the last take_stats()
  T cfl_reached_ = 0;           // largest max_speed dt / dx since the last take_stats()
  transfer::ParticleBins<Dim> bins_;
  DenseGrid dense_;    // domain.grid "dense"
  SparseGrid sparse_;  // domain.grid "sparse" (the unused one stays empty)
  bool sparse_grid_ = true;
  T dx_ = T(1);
  Vec origin_;
  Eigen::Matrix<int, Dim, 1> res_;  // grid nodes per axis
  Vec gravity_;
  Vec x_lo_, x_hi_;  // particles must stay in this box (the domain plus one cell)
  double time_ = 0;
  std::int64_t steps_ = 0;
  PhaseTimes phase_times_;
  T max_speed_ = 0;
  T max_wave_speed_ = 0;
  std::unique_ptr<ImplicitUpdate<T, Dim>> implicit_;  // null for "explicit"
  CgStats cg_;
  std::unique_ptr<SleepState> sleep_;  // null unless solver.sleep.speed > 0
  std::unique_ptr<Split> split_;       // null unless split over more than one process
};

extern template class MpmSolver<float, 2>;
extern template class MpmSolver<float, 3>;
extern template class MpmSolver<double, 2>;
extern template class MpmSolver<double, 3>;

}  // namespace slurry
