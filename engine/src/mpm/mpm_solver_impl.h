// Definition of MpmSolver<T, Dim>; included by one translation unit per (T, Dim) so that the
// four instantiations compile in parallel. This part holds the shared helpers, the sleeping and
// split state, construction (seeding the bodies) and the queries; the rest follows by concern:
// step.h (the substep and its opening phases), distribution.h (the split over MPI ranks),
// transfer_phases.h (P2G, grid update, G2P, return mapping), sleeping.h, state.h (statistics,
// checkpoint state, frames).
#pragma once
#include <Eigen/LU>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <cstring>
#include <sstream>
#include <type_traits>
#include <unordered_map>

#include "mpm/corotated_lanes.h"
#include "mpm/deformation_lanes.h"
#include "mpm/domain_split.h"
#include "frame_builder.h"
#include "geometry/scene_meshes.h"
#include "mpm/implicit_update.h"
#include "mpm/sand_lanes.h"
#include "state_io.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"
#include "slurry/transfer/transfers.h"

namespace slurry {

namespace detail {
/// Grid padding (nodes) outside the domain on every side: enough for the cubic kernel's support
/// of a particle one cell outside the domain.
constexpr int kPad = 3;

/// Portable uniform double in [0, 1) from a 64-bit generator (std::uniform_real_distribution is
/// not specified bit-for-bit across standard libraries; frames must be reproducible).
inline double uniform01(std::mt19937_64& rng) { return double(rng() >> 11) * 0x1.0p-53; }

/// Writes a mass or rest-volume channel of n particles as the vector of its n values, also
/// while it is stored once (the checkpoint format has one value per particle).
template <class T>
void write_scalar_channel(StateWriter& w, const ScalarChannel<T>& c, std::size_t n) {
  if (c.uniform())
    w.repeated(c.value(), n);
  else
    w.vec(c.values());
}

/// Reads what write_scalar_channel wrote into c: stored once if all n values have the same
/// bits, as seeding would have stored them (Particles::push_back), so that a resumed run
/// stores its particles as the uninterrupted one does.
template <class T>
void read_scalar_channel(StateReader& r, ScalarChannel<T>& c, std::int64_t n, const char* name) {
  const std::string_view bytes = r.vec_bytes<T>(n, name);
  bool same = true;
  for (std::size_t at = sizeof(T); at < bytes.size() && same; at += sizeof(T))
    same = std::memcmp(bytes.data() + at, bytes.data(), sizeof(T)) == 0;
  if (same) {
    T v = T(0);
    if (!bytes.empty()) std::memcpy(&v, bytes.data(), sizeof(T));
    c.assign_uniform(v);
  } else {
    std::vector<T> v(bytes.size() / sizeof(T));
    std::memcpy(v.data(), bytes.data(), bytes.size());
    c.assign(std::move(v));
  }
}

/// Whether particle p's volume ratio is the tracked J (a fluid) rather than det F (a solid).
template <class T, int Dim>
bool tracks_J(const Particles<T, Dim>& P, const std::vector<Material<T, Dim>>& materials, std::size_t p) {
  return !P.J.empty() && (P.F.empty() || materials[P.material.empty() ? 0 : P.material[p]].fluid);
}

/// A particle whose path x_before -> x (this substep, t0 to t1) entered a thin collider stops
/// just outside its surface and loses its velocity into it.
template <class T, int Dim>
void keep_out_of_colliders(Particles<T, Dim>& P, const std::vector<Collider<T, Dim>>& colliders,
                           const Eigen::Matrix<T, Dim, 1>* x_before, T t0, T t1, T dx) {
  const T margin = T(1e-3) * dx;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  const auto poses0 = collider_poses(colliders, t0), poses1 = collider_poses(colliders, t1);
  parallel::parallel_chunks(0, std::int64_t(P.size()), [&](std::int64_t lo, std::int64_t hi) {
    for (std::int64_t p = lo; p < hi; ++p) {
      const Vec x0 = x_before[p];
      for (std::size_t k = 0; k < colliders.size(); ++k) {
        const auto& c = colliders[k];
        if (!thin_collider(c, dx)) continue;
        Vec n;
        if (!stop_at_collider(c, x0, t0, poses0[k], P.x[p], t1, poses1[k], margin, n)) continue;
        const T vn = (P.v[p] - c.velocity_at(P.x[p], t1)).dot(n);
        if (vn < T(0)) P.v[p] -= vn * n;  // no velocity into the solid
      }
    }
  });
}

}  // namespace detail

/// State of sleeping material (solver.sleep). Blocks are keyed by their linear index in the
/// bins' block lattice (ParticleBins::group_key). A sleeping block keeps the grid contribution its particles made when it
/// fell asleep, split into the part that does not scale with the substep (mass; momentum is zero,
/// since its particles were stopped) and the stress impulse per second of substep, so that the
/// contribution of a substep dt is (dt * impulse, mass): the same sums the particles would
/// scatter, since at rest nothing else changes.
template <class T, int Dim>
struct MpmSolver<T, Dim>::SleepState {
  using Node = transfer::GridNode<T, Dim>;
  struct Block {
    std::uint32_t count = 0;  ///< particles in the block when it fell asleep
    T hardening = T(1);       ///< largest snow hardening factor of its particles (time-step limit)
    bool cached = false;      ///< `nodes` holds the block's patch (rebuilt after a resume)
    std::vector<Node> nodes;  ///< (momentum per unit dt, mass) per patch node
  };
  T speed = 0, rate = 0, wake = 0;
  int substeps = 0;
  std::vector<std::uint16_t> calm;  ///< per block: calm substeps in a row...
  std::vector<std::int64_t> seen;   ///< ...counted up to this step (older counts are void)
  std::unordered_map<std::int64_t, Block> asleep;
  /// The sleeping block of each occupied block (group) and of each bin of the current bins, or
  /// null where awake (node pointers of the map stay valid while others are added or erased).
  std::vector<Block*> group_block, bin_block;
  std::vector<std::uint8_t> group_calm;  ///< scratch of sleep_update
  std::int64_t woken = 0, slept = 0;     ///< blocks woken / put to sleep so far
};

/// The split over processes (mpm_solver.h, domain_split.h).
template <class T, int Dim>
struct MpmSolver<T, Dim>::Split {
  Communicator* comm = nullptr;
  detail::BoxSplit<Dim> boxes;  ///< rank r owns the blocks of box r
  IVec lo = IVec::Zero(), hi = IVec::Zero();  ///< this rank's box of blocks, [lo, hi)
  std::vector<int> peers;  ///< the ranks whose boxes touch this one's, ascending
  std::size_t total = 0;   ///< particles of all ranks (MPM keeps every particle)
  double fewest = 0, most = 0;  ///< particles of the emptiest and the fullest rank at the last rebalance
  double bytes_per_substep = 0;  ///< this rank's halo and migration bytes per substep over the last advance_to
  double halo_bytes_per_substep = 0;  ///< of which the grid halo's
  std::uint64_t halo_bytes = 0;       ///< grid halo bytes this rank has sent
  Particles<T, Dim> gathered;    ///< rank 0: every particle, as of the last frame()
  /// The grid halo (distribution.h): this rank's occupied blocks that touch another rank's box,
  /// the owners of their neighbours, and their patches' nodes, patch after patch; slot[g] is
  /// group g's (-1: none).
  std::vector<IVec> border;
  std::vector<int> border_owners;  ///< per border block, the owner of each neighbour (3^Dim, -1 outside the lattice)
  std::vector<transfer::GridNode<T, Dim>> kept;
  std::vector<std::int32_t> slot;
};

template <class T, int Dim>
MpmSolver<T, Dim>::MpmSolver(const Scene& scene, Communicator* communicator) : scene_(scene) {
  scene_.validate();
  const auto& dom = scene_.domain;
  const T dx = T(dom.dx);
  Eigen::Matrix<int, Dim, 1> res;
  Vec origin;
  for (int d = 0; d < Dim; ++d) {
    const int cells = int(std::ceil((dom.max[d] - dom.min[d]) / dom.dx - 1e-9));
    res[d] = cells + 1 + 2 * detail::kPad;
    origin[d] = T(dom.min[d] - detail::kPad * dom.dx);
    x_lo_[d] = T(dom.min[d] - dom.dx);
    x_hi_[d] = T(dom.min[d] + (cells + 1) * dom.dx);
  }
  dx_ = dx;
  origin_ = origin;
  res_ = res;
  const bool flip = scene_.solver.transfer == TransferKind::FLIP;
  sparse_grid_ = dom.grid == GridKind::Sparse || (dom.grid == GridKind::Auto && scene_.solver.integrator != Integrator::Implicit);
  if (sparse_grid_) {
    sparse_.resize(origin, dx, res);
    sparse_.keep_old_velocity(flip);
  } else {
    dense_.resize(origin, dx, res);
    dense_.keep_old_velocity(flip);
  }
  bins_.resize(res);
  gravity_ = scene_.solver.gravity.head<Dim>().template cast<T>();
  for (const auto& m : scene_.materials) materials_.push_back(make_material<T, Dim>(m));
  colliders_ = detail::make_colliders<T, Dim>(scene_);
  for (const auto& m : materials_) {
    max_wave_speed_ = std::max(max_wave_speed_, m.wave_speed);
    fluid_.push_back(m.fluid ? 1 : 0);
  }
  seed_bodies();
  for (const auto& v : particles_.v) max_speed_ = std::max(max_speed_, v.norm());
  if (scene_.solver.integrator == Integrator::Implicit) {
    typename ImplicitUpdate<T, Dim>::Options o;
    o.tolerance = T(scene_.solver.cg_tolerance);
    o.max_iterations = scene_.solver.cg_max_iterations;
    using Pre = typename ImplicitUpdate<T, Dim>::Preconditioner;
    o.preconditioner = scene_.solver.implicit_preconditioner == ImplicitPreconditioner::Jacobi        ? Pre::Jacobi
                       : scene_.solver.implicit_preconditioner == ImplicitPreconditioner::BlockJacobi ? Pre::BlockJacobi
                                                                                                      : Pre::IC0;
    implicit_ = std::make_unique<ImplicitUpdate<T, Dim>>(scene_.solver.kernel, scene_.solver.transfer, o);
  }
  if (scene_.solver.sleep.speed > 0) {
    const auto& sp = scene_.solver.sleep;
    sleep_ = std::make_unique<SleepState>();
    sleep_->speed = T(sp.speed);
    sleep_->rate = T(sp.strain_rate);
    sleep_->wake = T(sp.wake_speed > 0 ? sp.wake_speed : 2 * sp.speed);
    sleep_->substeps = sp.substeps;
    std::size_t blocks = 1;
    for (int d = 0; d < Dim; ++d) blocks *= std::size_t(bins_.block_res()[d]);
    sleep_->calm.assign(blocks, 0);
    sleep_->seen.assign(blocks, -2);
  }
  for (const auto& m : materials_)
    project_in_p2g_.push_back(std::holds_alternative<constitutive::HenckyStVK<T, Dim>>(m.elastic) &&
                              m.plastic_kind == PlasticModel::DruckerPrager && !implicit_);
  if (communicator && communicator->size() > 1) {
    const int ranks = communicator->size();
    if (implicit_ || sleep_)
      throw SceneError(scene_.source + ": " + (implicit_ ? "solver.integrator \"implicit\"" : "solver.sleep") +
                       ": runs in one process only; expected an explicit scene without solver.sleep for a run split over " +
                       std::to_string(ranks) + " processes (mpirun -np " + std::to_string(ranks) + "), or mpirun -np 1");
    split_ = std::make_unique<Split>();
    split_->comm = communicator;
    const IVec br = bins_.block_res();
    const auto per_axis = detail::process_grid<Dim>(ranks, br);
    if (per_axis.empty()) {
      std::string lattice;
      for (int d = 0; d < Dim; ++d) lattice += (d ? " x " : "") + std::to_string(br[d]);
      throw SceneError(scene_.source + ": domain: split over " + std::to_string(ranks) + " processes, but the grid's " +
                       lattice + " blocks (" + std::to_string(transfer::BlockShape<Dim>::size) +
                       " nodes along each axis of a block) give no box of at least one block to each; expected a process count "
                       "that factors into at most that many along each axis (mpirun -np)");
    }
    split_->boxes = detail::BoxSplit<Dim>(br, per_axis);
    split_->total = particles_.size();
    split_particles();
  }
}

template <class T, int Dim>
MpmSolver<T, Dim>::~MpmSolver() = default;

template <class T, int Dim>
void MpmSolver<T, Dim>::seed_bodies() {
  auto& P = particles_;
  P.channels.C = scene_.solver.transfer == TransferKind::MLS || scene_.solver.transfer == TransferKind::APIC;
  P.channels.material = scene_.materials.size() > 1;
  for (const auto& m : materials_) {
    P.channels.F = P.channels.F || !m.fluid;
    P.channels.J = P.channels.J || m.fluid;
    P.channels.plastic = P.channels.plastic || m.plastic_kind != PlasticModel::None;
  }
  // Bodies are seeded material by material, so every material owns one contiguous range.
  for (int mi = 0; mi < int(materials_.size()); ++mi) {
    for (std::size_t bi = 0; bi < scene_.bodies.size(); ++bi) {
      const auto& b = scene_.bodies[bi];
      if (scene_.material_index(b.material) != mi) continue;
      const auto& mat = materials_[mi];
      if (b.shape == Shape::Mesh) {
        if constexpr (Dim == 3) {
          double vol = 0;
          const auto xs = detail::seed_mesh_body(scene_, bi, vol);
          const Vec vel = b.velocity.template cast<T>();
          for (const auto& x : xs)
            P.push_back(x.template cast<T>(), vel, T(mat.density * vol), T(vol), std::uint16_t(mi), mat.initial_plastic_state());
        }
        continue;
      }
      Eigen::Matrix<double, Dim, 1> lo, hi;
      const Eigen::Matrix<double, Dim, 1> c = b.center.head<Dim>();
      if (b.shape == Shape::Box) {
        lo = b.min.head<Dim>();
        hi = b.max.head<Dim>();
      } else {
        lo = c.array() - b.radius;
        hi = c.array() + b.radius;
        if (b.shape == Shape::Cylinder) {
          lo[b.axis] = c[b.axis] - 0.5 * b.height;
          hi[b.axis] = c[b.axis] + 0.5 * b.height;
        }
      }
      const double h_target = scene_.domain.dx / std::pow(b.particles_per_cell, 1.0 / Dim);
      Eigen::Matrix<int, Dim, 1> n;
      Eigen::Matrix<double, Dim, 1> h;
      for (int d = 0; d < Dim; ++d) {
        n[d] = std::max(1, int(std::lround((hi[d] - lo[d]) / h_target)));
        h[d] = (hi[d] - lo[d]) / n[d];
      }
      const double vol = h.prod();
      std::mt19937_64 rng(b.seed);
      const Vec vel = b.velocity.head<Dim>().template cast<T>();
      const std::size_t before = P.size();
      Eigen::Matrix<int, Dim, 1> i = Eigen::Matrix<int, Dim, 1>::Zero();
      const std::int64_t total = std::int64_t(n.template cast<std::int64_t>().prod());
      for (std::int64_t k = 0; k < total; ++k) {
        std::int64_t r = k;
        for (int d = Dim - 1; d >= 0; --d) {
          i[d] = int(r % n[d]);
          r /= n[d];
        }
        Eigen::Matrix<double, Dim, 1> x;
        for (int d = 0; d < Dim; ++d) {
          const double u = b.sampling == Sampling::Jittered ? detail::uniform01(rng) : 0.5;
          x[d] = lo[d] + (i[d] + u) * h[d];
        }
        bool inside = true;
        if (b.shape == Shape::Sphere) {
          inside = (x - c).squaredNorm() <= b.radius * b.radius;
        } else if (b.shape == Shape::Cylinder) {
          Eigen::Matrix<double, Dim, 1> r2 = x - c;
          r2[b.axis] = 0;
          inside = r2.squaredNorm() <= b.radius * b.radius;
        }
        if (inside)
          P.push_back(x.template cast<T>(), vel, T(mat.density * vol), T(vol), std::uint16_t(mi),
                      mat.initial_plastic_state());
      }
      if (P.size() == before)
        throw SceneError(scene_.source + ": bodies[" + std::to_string(bi) +
                         "]: seeds no particles (expected a body larger than the particle spacing " +
                         detail::fmt(h_target) + ")");
    }
  }
}

template <class T, int Dim>
std::size_t MpmSolver<T, Dim>::particle_count() const {
  return split_ ? split_->total : particles_.size();
}

template <class T, int Dim>
std::size_t MpmSolver<T, Dim>::bytes() const {
  std::size_t sleeping = 0;
  if (sleep_) {
    sleeping = sleep_->calm.capacity() * sizeof(std::uint16_t) + sleep_->seen.capacity() * sizeof(std::int64_t);
    for (const auto& [k, blk] : sleep_->asleep) sleeping += sizeof(blk) + blk.nodes.capacity() * sizeof(blk.nodes[0]);
  }
  double b = double(particles_.bytes() + x_before_.capacity() * sizeof(Vec) +
                    reorder_done_.capacity() * sizeof(std::uint64_t) + bins_.bytes() + dense_.bytes() +
                    sparse_.bytes() + (implicit_ ? implicit_->bytes() : 0) + sleeping);
  if (split_) split_->comm->sum(&b, 1);
  return std::size_t(b);
}

template <class T, int Dim>
T MpmSolver<T, Dim>::stable_dt() const {
  const T dx = dx_;
  T dt = T(scene_.solver.max_dt);
  if (max_speed_ > T(0)) dt = std::min(dt, T(scene_.solver.cfl) * dx / max_speed_);
  // The linear B-spline tolerates a smaller elastic Courant number: free fall with APIC grows
  // round-off into ringing at elastic_cfl 0.5 and stays exact at 0.1 (tests/mpm/physics_test),
  // so its elastic limit is scaled by a quarter.
  const T kernel_factor = scene_.solver.kernel == KernelKind::Linear ? T(0.25) : T(1);
  if (max_wave_speed_ > T(0) && !implicit_)  // the implicit update has no elastic limit
    dt = std::min(dt, kernel_factor * T(scene_.solver.elastic_cfl) * dx / max_wave_speed_);
  return dt;
}

template <class T, int Dim>
std::int64_t MpmSolver<T, Dim>::advance_to(double t_end) {
  if (!split_)
    return substep_to(time_, t_end, [&] { return dt_scale_ * double(stable_dt()); }, [&](double dt) { step(T(dt)); }, scene_);
  auto& S = *split_;
  const std::uint64_t sent = S.comm->exchanged_bytes();
  rebalance();
  const std::uint64_t halo = S.halo_bytes;
  const auto n = substep_to(time_, t_end, [&] { return dt_scale_ * double(stable_dt()); }, [&](double dt) { step(T(dt)); }, scene_);
  if (n > 0) {
    S.bytes_per_substep = double(S.comm->exchanged_bytes() - sent) / double(n);
    S.halo_bytes_per_substep = double(S.halo_bytes - halo) / double(n);
  }
  return n;
}

template <class T, int Dim>
std::uint64_t MpmSolver<T, Dim>::halo_bytes_sent() const {
  return split_ ? split_->halo_bytes : 0;
}

template <class T, int Dim>
std::size_t MpmSolver<T, Dim>::sleeping_blocks() const {
  return sleep_ ? sleep_->asleep.size() : 0;
}

template <class T, int Dim>
std::int64_t MpmSolver<T, Dim>::blocks_fallen_asleep() const {
  return sleep_ ? sleep_->slept : 0;
}

template <class T, int Dim>
std::string MpmSolver<T, Dim>::solver_status() const {
  if (split_) {
    const auto& S = *split_;
    const double mean = double(S.total) / S.comm->size();
    std::string grid;
    for (int d = 0; d < Dim; ++d) grid += (d ? " x " : "") + std::to_string(S.boxes.procs[d]);
    char buf[240];
    std::snprintf(buf, sizeof buf,
                  "%d ranks in %s boxes: %.0f-%.0f particles per rank (imbalance %.3f), rank %d sent %.3g kB per "
                  "substep (grid halo %.3g kB) to %d peers",
                  S.comm->size(), grid.c_str(), S.fewest, S.most, mean > 0 ? S.most / mean : 1.0, S.comm->rank(),
                  S.bytes_per_substep / 1e3, S.halo_bytes_per_substep / 1e3, int(S.peers.size()));
    return buf;
  }
  if (sleep_) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "sleeping %zu blocks (%lld fell asleep, %lld woke so far)", sleep_->asleep.size(),
                  (long long)sleep_->slept, (long long)sleep_->woken);
    return buf;
  }
  if (!implicit_ || cg_.solves == 0) return {};
  char buf[160];
  std::snprintf(buf, sizeof buf, "implicit CG %d iterations, residual %.2g (%lld unconverged so far)",
                cg_.last_iterations, cg_.last_residual, (long long)cg_.unconverged);
  return buf;
}

}  // namespace slurry

#include "mpm/step.h"
#include "mpm/distribution.h"
#include "mpm/transfer_phases.h"
#include "mpm/sleeping.h"
#include "mpm/state.h"
