#pragma once
/// \file flip_solver.h
/// The FLIP/APIC liquid solver (Zhu & Bridson 2005, "Animating sand as a fluid"; Jiang et al.
/// 2015, APIC; Bridson, "Fluid Simulation for Computer Graphics", 2nd ed.): incompressible
/// liquid on a staggered grid, carried by marker particles. One substep is a fixed sequence of
/// named phases (the shape of Jet's PicSolver / FlipSolver / ApicSolver, without the class tree):
///
///   emit             emitters add particles (rate * dt of volume each)
///   sort             counting sort of the particles by cell (P2G scatters slab by slab from it)
///   transfer_to_grid P2G on the faces (PIC/FLIP: v; APIC: v + c . (x_f - x_p))
///   save_velocities  FLIP keeps the face velocities for the delta update
///   gravity          u += dt g
///   boundaries       solid face fractions and velocities (moving colliders: at t + dt),
///                    cell labels and the liquid level set phi from the particles; with
///                    surface tension (surface_tension > 0) also the surface's curvature, from
///                    a smooth level set of the particles (surface_tension.h)
///   viscosity        implicit viscous stress (viscosity.h, Batty & Bridson 2008); only when a
///                    material has viscosity > 0. After gravity and before the projection, as
///                    in the paper: the projection then removes the divergence the viscous step
///                    leaves. Where liquids of different viscosity mix, a cell's viscosity is
///                    the mean over its particles' materials (a cell without particles takes
///                    the largest of its neighbours'), so it varies in space with the particles
///   project          pressure projection (pressure.h: PCG, ghost fluid, variational solids;
///                    the free surface at p = sigma kappa with surface tension, else p = 0)
///   extrapolate      face velocities into the air (extrapolate.h); the air faces that carry
///                    particle mass keep their own velocity plus the projection's correction
///                    (extrapolate_velocities())
///   enforce_solids   closed faces take the solid's velocity
///   transfer_to_particles  G2P: PIC, FLIP (blend ratio) or APIC (affine vectors)
///   advect           x through the grid velocity (Euler, midpoint, Heun or RK3), pushed out
///                    of colliders and kept inside the domain; with the linear kernel in
///                    transfer_to_particles' pass (its timer then holds both)
///   reseed           particles per cell between solver.reseed bounds
///   whitewater       secondary spray, foam and bubbles (whitewater.h, Ihmsen et al. 2012);
///                    only when solver.whitewater.enabled (otherwise nothing is allocated).
///                    Last, on the substep's grid: the liquid's labels and phi at t and its
///                    projected velocity; one-way coupled (the liquid never sees them)
///
/// The substep is min(solver.max_dt, cfl dx / max |v_p|) with cfl up to 5, and with surface
/// tension at most Brackbill's capillary limit (surface_tension.h), clipped so frames land on
/// multiples of 1 / fps. Every phase is parallel over independent items with a fixed
/// summation order: frames are bitwise identical for any thread count.
///
/// Split over MPI ranks (a Communicator of more than one rank), each rank steps the same phases
/// on a window of the grid around its box of cells, with ghost particles before the transfer, the
/// pressure rows of its own cells solved by Communicator::solve_spd, and face values from their
/// owners after the projection and the extrapolation (engine/src/flip/split.h); frames agree with
/// one process's to the pressure solve's tolerance.
#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "slurry/engine/flip/cell_sort.h"
#include "slurry/engine/flip/extrapolate.h"
#include "slurry/engine/flip/face_transfer.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/pressure.h"
#include "slurry/engine/flip/seeding.h"
#include "slurry/engine/flip/solids.h"
#include "slurry/engine/flip/surface_tension.h"
#include "slurry/engine/flip/viscosity.h"
#include "slurry/engine/flip/whitewater.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/substeps.h"

namespace slurry::flip {
namespace detail {
template <class T, int Dim>
struct FlipSplit;
}  // namespace detail

/// Named phases of a substep, for the per-phase timing (FlipSolver::phase_seconds).
enum Phase : int {
  kEmit, kSort, kToGrid, kSave, kGravity, kBoundaries, kViscosity, kProject, kExtrapolate, kEnforce, kToParticles,
  kAdvect, kReseed,
  kWhitewater,
  kPhaseCount
};
const char* phase_name(int phase);

template <class T, int Dim>
class FlipSolver final : public Solver {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Grid = MacGrid<T, Dim>;

  /// Validates the scene (solver.type "flip") and seeds its bodies.
  /// With a communicator of more than one rank (every rank calls this with the same scene), the
  /// domain's cells are split into boxes, one per rank (flip/split.h in the engine's sources).
  explicit FlipSolver(const Scene& scene, Communicator* communicator = nullptr);
  ~FlipSolver() override;

  /// The substep the CFL condition allows now (not clipped to a frame boundary): advective_dt(),
  /// and with surface tension at most the capillary limit.
  T stable_dt() const;
  /// solver.max_dt, or the CFL step cfl dx / max speed where that is shorter.
  T advective_dt() const;
  /// One substep of length dt. Throws SimulationError on a non-finite state.
  void step(T dt);

  double time() const override { return time_; }
  std::int64_t steps() const override { return steps_; }
  std::size_t particle_count() const override;
  std::size_t bytes() const override;
  std::int64_t advance_to(double t_end) override;
  /// position, velocity, material, id (the persistent particle id, uint32).
  Frame frame(const std::vector<std::string>& attributes) const override;
  Frame frame_view(const std::vector<std::string>& attributes) const override;
  Frame own_frame(const std::vector<std::string>& attributes) const override;

  FlipParticles<T, Dim>& particles() { return particles_; }
  const FlipParticles<T, Dim>& particles() const { return particles_; }
  const Grid& grid() const { return grid_; }
  const Scene& scene() const { return scene_; }
  /// What the last pressure projection did (iterations, residual, max divergence).
  const ProjectionReport& last_projection() const { return last_projection_; }
  /// What the last viscosity solve did (zero unknowns when every material is inviscid).
  const ViscosityReport& last_viscosity() const { return last_viscosity_; }
  /// "pressure PCG <iterations> iterations, residual <r>, max |div u| <d> 1/s" of the last
  /// substep, and the viscosity PCG's iterations when a material is viscous.
  std::string solver_status() const override;
  /// Mass from the nominal particle volume (every particle carries dx^Dim / ppc); volume: the
  /// cells that hold a particle.
  RunStats take_stats() override;
  /// position, velocity, id, material (when the scene has more than one liquid).
  ParticleStorage particle_storage() const override;
  using Solver::save_state;
  void save_state(const StateSink& sink) const override;
  void load_state(std::string_view in, const std::string& what) override;
  /// A split run's part: this process's particles and its box's grid fields (output.per_rank).
  void save_own_state(const StateSink& sink) const override;
  /// The parts of a split run's per-process checkpoint, on any number of processes (one included):
  /// each process keeps the particles it owns and its window of the parts' fields.
  void load_state_parts(int parts, const std::function<std::string(int)>& part, const std::string& what) override;
  /// Largest particle speed after the last substep (m/s).
  T max_speed() const { return max_speed_; }
  /// Particle volume dx^Dim / particles_per_cell (the nominal seeding density).
  T particle_volume() const { return particle_volume_; }
  /// dx^Dim / particle_volume(): the particles per cell of the seeding.
  T particles_per_cell() const { return std::pow(grid_.dx, T(Dim)) / particle_volume_; }
  /// Liquid density (kg/m^3).
  T density() const { return T(scene_.materials[0].density); }
  /// sum_p m |v_p|^2 / 2 with m = density * particle_volume.
  T kinetic_energy() const;
  /// Fluid cells after the last substep times dx^Dim.
  T fluid_cell_volume() const;
  /// Particles added and removed by reseeding so far.
  std::int64_t reseeded_added() const { return reseed_added_; }
  std::int64_t reseeded_removed() const { return reseed_removed_; }
  /// The secondary particles (solver.whitewater), or null when the scene has none.
  const Whitewater<T, Dim>* whitewater() const { return whitewater_.get(); }
  /// The secondary particles by type, over every process of a split run (as of the last
  /// advance_to()); zero without whitewater.
  WhitewaterCounts whitewater_counts() const;
  Whitewater<T, Dim>* whitewater() { return whitewater_.get(); }
  /// The secondary particles as a frame: x, y(, z), vx, vy(, vz), type (uchar), id (uint),
  /// borrowed; no tables without whitewater.
  Frame whitewater_frame_view() const override;
  /// Wall seconds spent in each phase so far (index: Phase).
  const std::array<double, kPhaseCount>& phase_seconds() const { return phase_seconds_; }
  /// CPU seconds of the process (all threads) spent in each phase so far (std::clock).
  const std::array<double, kPhaseCount>& phase_cpu_seconds() const { return phase_cpu_seconds_; }

 private:
  void emit(T dt);
  void sort_particles();
  void transfer_to_grid();
  void save_velocities();
  void apply_gravity(T dt);
  void build_boundaries(T t);
  void apply_viscosity(T dt);
  void project(T dt);
  /// The extrapolate phase: fill_air_velocities(), except on the air faces with particle mass
  /// where particles move slowly, which keep their P2G velocity plus the projection's change.
  void extrapolate_velocities(T dt);
  /// Face velocities extrapolated into the air from the faces the projection updated, as far
  /// as the advection reads.
  void fill_air_velocities();
  void enforce_solids();
  /// With the linear kernel G2P advects each particle as soon as it has its velocity: the grid
  /// velocity it gathered at x_p is the advection's first stage, and the particles are read and
  /// written once. advect() is the separate pass of the quadratic kernel.
  bool advects_in_g2p() const { return order_ == 1; }
  /// G2P; where advects_in_g2p(), also the advection over dt.
  void transfer_to_particles(T dt);
  void advect(T dt);
  void reseed();

  /// advect()'s step for one particle, shared with G2P's pass for the linear kernel: the
  /// substep's constants and collider poses, computed once per substep.
  class Advection {
   public:
    Advection(FlipSolver& sim, T dt);
    /// Moves particle p one step of the scene's advection scheme (advection.h), from its first
    /// stage k1 = u(x_p), then stops it at thin colliders and keeps it out of solids.
    void particle(std::int64_t p, const Vec& k1) const;
    /// The grid velocity u(x) that advection integrates (trilinear on the faces).
    Vec velocity(const Vec& x) const;

   private:
    FlipSolver& sim_;
    T dt_, t0_, t_end_, margin_;
    AdvectionScheme scheme_;
    bool solids_, thin_;
    std::vector<geometry::Pose> poses0_, poses1_;
  };

  // A run split over processes (flip/split.h).
  void split_particles();
  void fit_window();
  void rebalance();
  void send_to_owners(const std::vector<int>& ranks);
  void exchange_ghosts();
  void drop_ghosts();
  void migrate();
  template <class Target>
  ProjectionReport split_projection(T dt, const Target& target_flux);
  std::vector<double> own_cell_counts(int depth = 1) const;
  FlipParticles<T, Dim> gather_particles() const;
  // Whitewater split over processes (split_whitewater.cpp): the substep's phase, the particles
  // handed to the owners of their cells (peers, or every rank), the limit over every rank, the
  // counts summed over the ranks, every rank's particles on rank 0 in id order.
  void split_whitewater(T dt);
  void send_whitewater_to_owners(bool everyone);
  void limit_split_whitewater();
  void count_split_whitewater();
  WhitewaterParticles<T, Dim> gather_whitewater() const;
  // One process's part of a split run's state (output.per_rank checkpoints): which of how many,
  // and its box of cells, [lo, hi), over which the part holds the grid fields.
  struct StatePart {
    int rank = 0, ranks = 1;
    IVec lo = IVec::Zero(), hi = IVec::Zero();
  };
  // `whitewater`, `generated`, `removed`: the secondary particles and their counters to write
  // instead of this process's (a split run's, gathered).
  void write_state(const StateSink& out, const FlipParticles<T, Dim>& P, const Grid& grid,
                   const StatePart* part = nullptr, const WhitewaterParticles<T, Dim>* whitewater = nullptr,
                   std::int64_t generated = 0, std::int64_t removed = 0) const;
  void read_state(std::string_view in, const std::string& what, FlipParticles<T, Dim>& P, Grid& grid,
                  StatePart* part = nullptr);
  Scene scene_;
  FlipSolver(const FlipSolver&) = delete;
  FaceScheme scheme_ = FaceScheme::APIC;
  int order_ = 1;
  FlipParticles<T, Dim> particles_;
  typename FlipParticles<T, Dim>::PermuteBuffers permute_spare_;  // sort_particles()' spare channel
  CellSort<T, Dim> sort_;
  Grid grid_;
  std::array<std::vector<T>, Dim> weight_sum_, old_u_;
  // The face velocities before the projection; extrapolate_velocities() reuses the storage.
  std::array<std::vector<T>, Dim> pre_u_;
  std::vector<std::uint8_t> holes_;
  bool faces_ready_ = false;
  Solids<T, Dim> solids_;
  std::vector<Emitter<T, Dim>> emitters_;
  Reseeder<T, Dim> reseeder_;
  PressureSolver<T, Dim> pressure_;
  Extrapolator<T, Dim> extrapolator_;
  ProjectionOptions projection_options_;
  ProjectionReport last_projection_;
  ViscositySolver<T, Dim> viscosity_;
  ViscosityReport last_viscosity_;
  SurfaceTension<T, Dim> surface_tension_;
  T sigma_ = 0;                  // surface tension (N/m), 0 = none
  bool viscous_ = false;         // a material has viscosity > 0
  bool subcell_surface_ = false; // solver.free_surface resolved: the surface placed inside the cells
  bool mixed_viscosity_ = false; // materials of different viscosities: mu per cell (cell_mu_)
  std::vector<T> material_mu_, cell_mu_, viscosity_scratch_;
  std::unique_ptr<Whitewater<T, Dim>> whitewater_;  // only when solver.whitewater.enabled
  Vec gravity_, x_lo_, x_hi_;
  T particle_volume_ = 0, particle_radius_ = 0, max_speed_ = 0;
  T cfl_reached_ = 0;  // largest max_speed dt / dx since the last take_stats()
  double time_ = 0;
  std::int64_t steps_ = 0, reseed_added_ = 0, reseed_removed_ = 0;
  std::array<double, kPhaseCount> phase_seconds_{}, phase_cpu_seconds_{};
  std::unique_ptr<detail::FlipSplit<T, Dim>> split_;  // only in a run split over processes
};

extern template class FlipSolver<float, 2>;
extern template class FlipSolver<float, 3>;
extern template class FlipSolver<double, 2>;
extern template class FlipSolver<double, 3>;

}  // namespace slurry::flip
