// Definition of MpmSolver<T, Dim>; included by one translation unit per (T, Dim) so that the
// four instantiations compile in parallel.
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

/// The split over processes (simulation.h, domain_split.h).
template <class T, int Dim>
struct MpmSolver<T, Dim>::Split {
  Communicator* comm = nullptr;
  int axis = 0;            ///< the split axis: the block lattice's longest
  std::vector<int> cuts;   ///< rank r owns block columns [cuts[r], cuts[r + 1]) along `axis`
  int lo = 0, hi = 0;      ///< this rank's columns
  std::size_t owned = 0;   ///< particles [0, owned) are this rank's; a substep's ghosts follow them
  std::size_t total = 0;   ///< particles of all ranks (MPM keeps every particle)
  double fewest = 0, most = 0;  ///< particles of the emptiest and the fullest rank at the last rebalance
  double bytes_per_substep = 0;  ///< this rank's halo and migration bytes per substep over the last advance_to
  Particles<T, Dim> gathered;    ///< rank 0: every particle, as of the last frame()
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
    const auto& br = bins_.block_res();
    for (int d = 1; d < Dim; ++d)
      if (br[d] > br[split_->axis]) split_->axis = d;
    if (br[split_->axis] < ranks)
      throw SceneError(scene_.source + ": domain: split over " + std::to_string(ranks) + " processes, but the grid has " +
                       std::to_string(br[split_->axis]) + " block columns (" + std::to_string(transfer::BlockShape<Dim>::size) +
                       " nodes each) along its longest axis; expected at most that many processes (mpirun -np)");
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
  // round-off into ringing at elastic_cfl 0.5 and stays exact at 0.1 (tests/engine/physics_test),
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
  const auto n = substep_to(time_, t_end, [&] { return dt_scale_ * double(stable_dt()); }, [&](double dt) { step(T(dt)); }, scene_);
  if (n > 0) S.bytes_per_substep = double(S.comm->exchanged_bytes() - sent) / double(n);
  return n;
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
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "%d ranks along %c: %.0f-%.0f particles per rank (imbalance %.3f), rank %d sent %.3g kB per substep",
                  S.comm->size(), "xyz"[S.axis], S.fewest, S.most, mean > 0 ? S.most / mean : 1.0, S.comm->rank(),
                  S.bytes_per_substep / 1e3);
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

template <class T, int Dim>
void MpmSolver<T, Dim>::step(T dt) {
  if (sparse_grid_)
    step_on(sparse_, dt);
  else
    step_on(dense_, dt);
  time_ += double(dt);
  ++steps_;
}

template <class T, int Dim>
template <class G>
void MpmSolver<T, Dim>::step_on(G& grid, T dt) {
  using Clock = std::chrono::steady_clock;
  auto t = Clock::now();
  auto lap = [&](double& phase) {
    const auto now = Clock::now();
    phase += std::chrono::duration<double>(now - t).count();
    t = now;
  };
  if (split_) {
    // Re-sorted before the ghosts join (they are dropped at the end of the substep).
    if (steps_ % kReorderInterval == 0) {
      bin_particles();
      reorder_particles();
    }
    add_ghosts();
  }
  bin_particles();
  lap(phase_times_.binning);
  if (!split_ && (implicit_ || steps_ % kReorderInterval == 0)) reorder_particles();
  lap(phase_times_.reorder);
  if (sleep_) sleep_prepare();
  particles_to_grid(grid, dt);
  lap(phase_times_.p2g);
  if constexpr (std::is_same_v<G, DenseGrid>) {
    if (implicit_)
      update_grid_implicit(grid, dt);
    else
      update_grid(grid, dt);
  } else {
    update_grid(grid, dt);
  }
  if (sleep_) {
    switch (scene_.solver.kernel) {
      case KernelKind::Linear: sleep_wake<1>(grid); break;
      case KernelKind::Quadratic: sleep_wake<2>(grid); break;
      case KernelKind::Cubic: sleep_wake<3>(grid); break;
    }
  }
  lap(phase_times_.grid);
  // Colliders act on grid nodes inside them, and a particle takes the velocity of every node
  // around it, including those beyond a collider thinner than the kernel's reach: such a wall
  // leaks (tests/extremes: a block at 20 m/s passed a wall dx/4 thick). For thin colliders the
  // positions before the move are kept (x_before_, allocated for such scenes only) and a particle
  // whose path enters one stops at its surface (detail::keep_out_of_colliders). Thick colliders
  // are left to the grid alone, as before.
  const bool thin_colliders = any_thin_collider(colliders_, dx_);
  if (thin_colliders) x_before_ = particles_.x;
  grid_to_particles(grid, dt);
  if (split_) detail::truncate_particles(particles_, split_->owned);  // the ghosts have served
  if (thin_colliders)
    detail::keep_out_of_colliders(particles_, colliders_, x_before_.data(), T(time_), T(time_) + dt, dx_);
  lap(phase_times_.g2p);
  return_mapping();
  if (sleep_) sleep_update();
  lap(phase_times_.plasticity);
  if (split_) migrate();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::project_and_stress(int material, std::uint32_t begin, std::uint32_t end, T dt, Mat* K,
                                            std::int64_t& yielded) {
  // Sand: the return mapping of this substep, then the stress from its SVD (plasticity.h).
  auto& P = particles_;
  const std::uint32_t* order = bins_.order();
  const auto& mat = materials_[std::size_t(material)];
  const T* vol0 = P.vol0.read_base();
  const std::size_t vol0_mask = P.vol0.read_mask();
  const auto& dp = mat.drucker_prager;
  if constexpr (Dim == 3 && constitutive::lanes::kPays<T>) {
    yielded += detail::project_and_stress_lanes<T>(dp, mat.mu, mat.lambda, dt, order, begin, end, P.F.data(),
                                                   P.plastic.data(), vol0, vol0_mask, K);
    return;
  }
  std::int64_t n = 0;
  Mat tau;
  for (auto i = begin; i < end; ++i) {
    const auto p = order[i];
    n += dp.project_with_stress(P.F[p], P.plastic[p], mat.mu, mat.lambda, tau);
    K[i - begin] = (-dt * vol0[p & vol0_mask]) * tau;
  }
  yielded += n;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::compute_stress(int material, std::uint32_t begin, std::uint32_t end, T dt, Mat* K) const {
  // One bin is one material: the model is dispatched once per bin, not per particle. The rest
  // volume is stored once or per particle (particles.h): the same loop reads both.
  const auto& P = particles_;
  const std::uint32_t* order = bins_.order();
  const auto& mat = materials_[std::size_t(material)];
  const T* vol0 = P.vol0.read_base();
  const std::size_t vol0_mask = P.vol0.read_mask();
  if (mat.fluid) {
    // tau = -J p(J) I, so K = -dt V0 tau = dt V0 J p I.
    const auto& fluid = mat.fluid_model();
    for (auto i = begin; i < end; ++i) {
      const auto p = order[i];
      K[i - begin] =
          Mat::Identity() * (dt * vol0[p & vol0_mask] * fluid.kirchhoff_pressure(P.J[p]));
    }
    return;
  }
  mat.visit_elastic([&](const auto& model) {
    using Model = std::decay_t<decltype(model)>;
    if constexpr (constitutive::lanes::kPays<T> &&
                  std::is_same_v<Model, constitutive::FixedCorotated<T, Dim>>) {
      // Jelly and snow: the stress over SIMD lanes (corotated_lanes.h); snow's hardening factors
      // first, one per particle.
      const bool snow = mat.plastic_kind == PlasticModel::Snow;
      T factor[kStressChunk];
      if (snow) {
        for (auto i = begin; i < end; ++i) factor[i - begin] = P.plastic[order[i]];
        mat.snow.hardening_factors(factor, std::ptrdiff_t(end - begin));
      }
      detail::fixed_corotated_stress_lanes<T, Dim>(model.mu, model.lambda, snow ? factor : nullptr,
                                                   dt, order, begin, end, P.F.data(), vol0,
                                                   vol0_mask, K);
      return;
    }
    if (mat.plastic_kind == PlasticModel::Snow) {
      for (auto i = begin; i < end; ++i) {
        const auto p = order[i];
        const auto scaled = model.scaled(mat.hardening_factor(P.plastic[p]));
        K[i - begin] = (-dt * vol0[p & vol0_mask]) * scaled.kirchhoff(P.F[p]);
      }
    } else {
      for (auto i = begin; i < end; ++i) {
        const auto p = order[i];
        K[i - begin] = (-dt * vol0[p & vol0_mask]) * model.kirchhoff(P.F[p]);
      }
    }
  });
}

template <class T, int Dim>
void MpmSolver<T, Dim>::update_grid_implicit(DenseGrid& grid, T dt) {
  // The implicit solve walks particles by (block, material) bins in storage order: particles are
  // re-stored in bin order every substep for it (step_on), so the bins are storage ranges.
  const auto r = implicit_->update_grid(grid, particles_, materials_, bins_.bins(), grid_boundaries(T(time_) + dt),
                                        gravity_, dt);
  cg_.last_iterations = r.iterations;
  cg_.last_residual = double(r.residual);
  ++cg_.solves;
  cg_.iterations += r.iterations;
  if (!r.converged) {
    // Not silent: counted in cg_stats(), named by diagnose() if the state then blows up, and
    // reported once on stderr.
    if (cg_.unconverged++ == 0)
      std::fprintf(stderr,
                   "slurry: warning: %s: implicit CG did not converge at step %lld (t = %g s): relative residual "
                   "%g after %d iterations (solver.cg_tolerance %g, solver.cg_max_iterations %d); further "
                   "occurrences are counted silently\n",
                   scene_.source.c_str(), (long long)(steps_ + 1), time_ + double(dt), double(r.residual),
                   r.iterations, scene_.solver.cg_tolerance, scene_.solver.cg_max_iterations);
  }
}

template <class T, int Dim>
void MpmSolver<T, Dim>::bin_particles() {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: bin_particles_order<1>(); break;
    case KernelKind::Quadratic: bin_particles_order<2>(); break;
    case KernelKind::Cubic: bin_particles_order<3>(); break;
  }
}

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::bin_particles_order() {
  const Vec* x = particles_.x.data();
  const T inv_dx = T(1) / dx_;
  const std::uint16_t* material = particles_.material.empty() ? nullptr : particles_.material.data();
  const std::uint32_t* id = particles_.id.data();
  const Vec origin = origin_;
  const transfer::PositionBases<Order, T, Dim> base_of{x, origin, inv_dx};
  const transfer::ChannelValues<std::uint16_t> material_of{material};
  const transfer::ChannelValues<std::uint32_t, false> rank_of{id};
  // Few particles change blocks in a substep: the last substep's bins, updated (the same bins
  // and order as a full build, blocks.h), when that is cheaper.
  if (bins_.update(std::int64_t(particles_.size()), base_of, material_of, rank_of)) return;
  bins_.build(std::int64_t(particles_.size()), base_of, material_of, int(materials_.size()));
  // Within a bin by persistent id: every patch sum then depends on which particles a block holds,
  // not on the storage's history (re-sorts, particles that came from another rank).
  bins_.sort_within_bins(rank_of);
}

template <class T, int Dim>
template <int Order>
int MpmSolver<T, Dim>::column_order(const Vec& x) const {
  // The expression of bin_particles_order, so that a particle's column is its bin's.
  const int d = split_->axis;
  const T inv_dx = T(1) / dx_;
  return transfer::BSpline<Order>::base((x[d] - origin_[d]) * inv_dx) >> transfer::BlockShape<Dim>::log2;
}

template <class T, int Dim>
int MpmSolver<T, Dim>::column(const Vec& x) const {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: return column_order<1>(x);
    case KernelKind::Quadratic: return column_order<2>(x);
    case KernelKind::Cubic: break;
  }
  return column_order<3>(x);
}

template <class T, int Dim>
bool MpmSolver<T, Dim>::owned_block(const Eigen::Matrix<int, Dim, 1>& block) const {
  return !split_ || (block[split_->axis] >= split_->lo && block[split_->axis] < split_->hi);
}

template <class T, int Dim>
bool MpmSolver<T, Dim>::set_borders(const std::vector<double>& counts) {
  auto& S = *split_;
  const int ranks = S.comm->size(), rank = S.comm->rank();
  const auto cuts = detail::balanced_cuts(counts, ranks);
  S.fewest = double(S.total), S.most = 0;
  for (int r = 0; r < ranks; ++r) {
    double n = 0;
    for (int c = cuts[std::size_t(r)]; c < cuts[std::size_t(r) + 1]; ++c) n += counts[std::size_t(c)];
    S.fewest = std::min(S.fewest, n), S.most = std::max(S.most, n);
  }
  if (cuts == S.cuts) return false;
  S.cuts = cuts;
  S.lo = S.cuts[std::size_t(rank)];
  S.hi = S.cuts[std::size_t(rank) + 1];
  return true;
}

template <class T, int Dim>
std::vector<double> MpmSolver<T, Dim>::column_counts() const {
  std::vector<double> counts(std::size_t(bins_.block_res()[split_->axis]), 0.0);
  for (const auto& x : particles_.x) counts[std::size_t(column(x))] += 1;
  return counts;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::split_particles() {
  // Every rank holds the same full set here, so every rank computes the same borders.
  auto& S = *split_;
  S.cuts.clear();
  set_borders(column_counts());
  std::vector<std::uint8_t> drop(particles_.size());
  for (std::size_t p = 0; p < drop.size(); ++p) {
    const int c = column(particles_.x[p]);
    drop[p] = c < S.lo || c >= S.hi;
  }
  detail::drop_particles(particles_, drop);
  S.owned = particles_.size();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::rebalance() {
  auto counts = column_counts();
  split_->comm->sum(counts.data(), int(counts.size()));
  if (set_borders(counts)) migrate();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::migrate() {
  auto& S = *split_;
  auto& P = particles_;
  for (;;) {
    std::vector<std::uint32_t> down, up;
    std::vector<std::uint8_t> drop(P.size(), 0);
    for (std::size_t p = 0; p < P.size(); ++p) {
      const int c = column(P.x[p]);
      if (c < S.lo) down.push_back(std::uint32_t(p)), drop[p] = 1;
      if (c >= S.hi) up.push_back(std::uint32_t(p)), drop[p] = 1;
    }
    std::string to_lower, to_upper;
    if (!down.empty()) detail::pack_particles(P, down, to_lower);
    if (!up.empty()) detail::pack_particles(P, up, to_upper);
    if (!down.empty() || !up.empty()) detail::drop_particles(P, drop);
    const auto [from_lower, from_upper] = S.comm->exchange(to_lower, to_upper);
    detail::unpack_particles(from_lower, P);
    detail::unpack_particles(from_upper, P);
    // After a substep one round settles every particle (each moved less than a column, and every
    // slab is a column wide at least); after new borders, particles pass one rank per round.
    double stray = 0;
    for (const auto& x : P.x) {
      const int c = column(x);
      stray += c < S.lo || c >= S.hi;
    }
    S.comm->max(&stray, 1);
    if (stray == 0) break;
  }
  S.owned = P.size();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::add_ghosts() {
  auto& S = *split_;
  auto& P = particles_;
  const int rank = S.comm->rank(), ranks = S.comm->size();
  S.owned = P.size();
  std::vector<std::uint32_t> down, up;
  for (std::size_t p = 0; p < P.size(); ++p) {
    const int c = column(P.x[p]);
    if (rank > 0 && c == S.lo) down.push_back(std::uint32_t(p));
    if (rank + 1 < ranks && c == S.hi - 1) up.push_back(std::uint32_t(p));
  }
  std::string to_lower, to_upper;
  if (!down.empty()) detail::pack_particles(P, down, to_lower);
  if (!up.empty()) detail::pack_particles(P, up, to_upper);
  const auto [from_lower, from_upper] = S.comm->exchange(to_lower, to_upper);
  detail::unpack_particles(from_lower, P);
  detail::unpack_particles(from_upper, P);
}

template <class T, int Dim>
Particles<T, Dim> MpmSolver<T, Dim>::all_particles(bool on_every_rank) const {
  std::vector<std::uint32_t> mine(particles_.size());
  for (std::size_t p = 0; p < mine.size(); ++p) mine[p] = std::uint32_t(p);
  std::string packed;
  detail::pack_particles(particles_, mine, packed);
  Particles<T, Dim> all = particles_.empty_like();
  const auto parts = on_every_rank ? split_->comm->all_gather(packed) : split_->comm->gather(packed);
  for (const auto& part : parts) detail::unpack_particles(part, all);
  return all;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::reorder_particles() {
  // Particles are stored in bin order, so that the transfers stream through memory. Each channel
  // is permuted in place by following the cycles of the order (new[j] = old[order[j]]): one
  // value of temporary storage and one bit per particle, where a gather through a scratch
  // channel would hold a second copy of the largest channel (36 bytes per particle in 3D float).
  // The particles moved in a few substeps, so the cycles are short and local. Each walk is
  // serial, bound by memory latency; the channels are shared out between the threads, each
  // with a bitmap of its own (the parallel gather of one channel was slower on two threads than
  // on one, RESULTS.md 2026-11-21). Channel k goes to task k mod tasks, one task per thread: in
  // the order of for_each_channel, two tasks pair x with F and v with C.
  auto& P = particles_;
  const std::uint32_t* order = bins_.order();
  const std::size_t n = P.size(), words = (n + 63) / 64;
  // One channel's walk, on values only (captures by value: the loop keeps them in registers).
  auto walk = [order, n, words](auto* c, std::uint64_t* done) {
    std::fill(done, done + words, 0);
    for (std::size_t i = 0; i < n; ++i) {
      if (done[i >> 6] >> (i & 63) & 1) continue;
      if (order[i] == i) continue;  // a fixed point is never reached from another cycle
      const auto first = c[i];
      std::size_t j = i;
      for (;;) {
        done[j >> 6] |= std::uint64_t(1) << (j & 63);
        const std::size_t next = order[j];
        if (next == i) break;
        c[j] = c[next];
        j = next;
      }
      c[j] = first;
    }
  };
  int channels = 0;
  P.for_each_channel([&](auto& channel) { channels += !channel.empty(); });
  const int groups = std::max(1, std::min(channels, parallel::max_threads()));
  reorder_done_.resize(std::size_t(groups) * words);
  auto group = [&](int g) {
    int k = 0;
    P.for_each_channel([&](auto& channel) {
      if (!channel.empty() && k++ % groups == g) walk(channel.data(), reorder_done_.data() + std::size_t(g) * words);
    });
  };
  if (groups == 1)
    group(0);
  else
    parallel::parallel_tasks(0, groups, [&](std::int64_t g) { group(int(g)); });
  bins_.reset_order();
}

template <class T, int Dim>
template <class G>
void MpmSolver<T, Dim>::particles_to_grid(G& grid, T dt) {
  grid.activate(bins_.bins());
  projected_scratch_.assign(bins_.bins().size(), 0);  // return_mapping() starts it again
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: particles_to_grid_order<1>(grid, dt); break;
    case KernelKind::Quadratic: particles_to_grid_order<2>(grid, dt); break;
    case KernelKind::Cubic: particles_to_grid_order<3>(grid, dt); break;
  }
  // Ghosts (split runs) were projected as well, for their stress; count the rank's own only.
  for (std::size_t b = 0; b < projected_scratch_.size(); ++b)
    if (owned_block(bins_.bins()[b].block)) projected_ += projected_scratch_[b];
}

template <class T, int Dim>
template <int Order, class G>
void MpmSolver<T, Dim>::particles_to_grid_order(G& grid, T dt) {
  using transfer::Scheme;
  const auto& bins = bins_.bins();
  const T inv_dx = T(1) / dx_;
  auto scatter = [&](auto scheme) {
    constexpr Scheme S = decltype(scheme)::value;
    if constexpr (S == Scheme::MLS && Order == 1) {
      return;  // rejected by Scene::validate
    } else {
      // Colour by colour; within a colour no two blocks write the same node (blocks.h).
      for (int c = 0; c < transfer::BlockShape<Dim>::colours; ++c) {
        const auto& list = bins_.colour(c);
        parallel::parallel_tasks(0, std::int64_t(list.size()), [&](std::int64_t i) {
          const std::size_t g = list[std::size_t(i)];
          const auto first = bins_.group_begin(g), last = bins_.group_begin(g + 1);
          transfer::Patch<T, Dim, Order> patch(bins[first].block, origin_, dx_, inv_dx);
          patch.zero();
          if (sleep_ && sleep_->group_block[g]) {
            // A sleeping block adds the contribution its particles made when they stopped; the
            // first substep after it fell asleep (or a resume) scatters them once, with the
            // stress impulse of a unit substep, to keep it.
            auto& blk = *sleep_->group_block[g];
            if (!blk.cached) {
              // Their return mapping was applied when they fell asleep (sleep_update): the
              // stress alone, so that a resume, which scatters them again, finds the same.
              for (auto b = first; b < last; ++b) scatter_bin<Order, S>(patch, bins[b], T(1), false);
              blk.nodes.assign(patch.nodes.begin(), patch.nodes.end());
              blk.cached = true;
            }
            for (std::size_t k = 0; k < blk.nodes.size(); ++k) {
              patch.nodes[k].template head<Dim>() = dt * blk.nodes[k].template head<Dim>();
              patch.nodes[k][Dim] = blk.nodes[k][Dim];
            }
            grid.add_patch(patch);
            return;
          }
          for (auto b = first; b < last; ++b) scatter_bin<Order, S>(patch, bins[b], dt, true);
          grid.add_patch(patch);
        });
      }
    }
  };
  switch (scene_.solver.transfer) {
    case TransferKind::PIC:
    case TransferKind::FLIP: scatter(std::integral_constant<Scheme, Scheme::PIC>{}); break;
    case TransferKind::APIC: scatter(std::integral_constant<Scheme, Scheme::APIC>{}); break;
    case TransferKind::MLS: scatter(std::integral_constant<Scheme, Scheme::MLS>{}); break;
  }
}

template <class T, int Dim>
template <int Order, transfer::Scheme S, class Patch>
void MpmSolver<T, Dim>::scatter_bin(Patch& patch, const typename transfer::ParticleBins<Dim>::Bin& bin, T dt,
                                     bool project) {
  // The stress of a bin's particles is computed just before they are scattered, a batch at a
  // time into a stack buffer that stays in L1: the step makes one parallel pass over the
  // particles before the grid update, and keeps no stress per particle. The scatter adds the
  // particles to the patch in the same order whatever the batches, so the sums are bitwise those
  // of one batch per bin.
  const auto& P = particles_;
  const Mat* C = P.C.empty() ? nullptr : P.C.data();
  alignas(64) Mat K[kStressChunk];
  for (std::uint32_t lo = bin.begin; lo < bin.end; lo += kStressChunk) {
    const std::uint32_t hi = std::min(bin.end, lo + kStressChunk);
    if (project && project_in_p2g_[bin.material])
      project_and_stress(int(bin.material), lo, hi, dt, K, projected_scratch_[std::size_t(&bin - bins_.bins().data())]);
    else
      compute_stress(int(bin.material), lo, hi, dt, K);
    transfer::scatter_particles<Order, S>(patch, P.x.data(), P.v.data(), P.m.read_base(), C, K,
                                          bins_.order(), lo, hi, std::int64_t(P.m.read_mask()));
  }
}

template <class T, int Dim>
GridBoundaries<T, Dim> MpmSolver<T, Dim>::grid_boundaries(T t) const {
  GridBoundaries<T, Dim> bc;
  bc.lo = detail::kPad + scene_.boundaries.thickness;  // nodes with index < lo are in the wall
  for (int d = 0; d < Dim; ++d) bc.hi[d] = res_[d] - 1 - detail::kPad - scene_.boundaries.thickness;
  bc.walls = scene_.boundaries.walls;
  bc.friction = T(scene_.boundaries.friction);
  bc.colliders = &colliders_;
  bc.time = t;
  return bc;
}

template <class T, int Dim>
template <class G>
void MpmSolver<T, Dim>::update_grid(G& grid, T dt) {
  using IVec = Eigen::Matrix<int, Dim, 1>;
  const GridBoundaries<T, Dim> bc = grid_boundaries(T(time_) + dt);
  using Node = typename G::Node;
  // v = p / m + dt g at a node with mass (a NaN mass too, so that the step's check finds it);
  // FLIP keeps p / m as the old velocity.
  auto advance = [&](Node& node, Vec* old) {
    Vec v = node.template head<Dim>() / node[Dim];
    if (old) *old = v;
    v += dt * gravity_;
    return v;
  };
  // Blocks (rows) that no wall or collider reaches skip the conditions (per node, their tests
  // cost 8% of a 2D snow substep). A collider counts as reaching a block within a cell of it.
  auto free = [&](const IVec& lo, const IVec& hi) {
    for (int d = 0; d < Dim; ++d)
      if (lo[d] < bc.lo || hi[d] > bc.hi[d]) return false;
    if (bc.colliders) {
      const Vec x_lo = origin_ + dx_ * lo.template cast<T>(), x_hi = origin_ + dx_ * hi.template cast<T>();
      for (const auto& c : *bc.colliders)
        if (c.may_reach(x_lo, x_hi, bc.time, dx_)) return false;
    }
    return true;
  };
  grid.for_each_active_node(
      free,
      [&](Node* nodes, Vec* old, std::int64_t n) {
        for (std::int64_t k = 0; k < n; ++k)
          if (!(nodes[k][Dim] <= T(0))) nodes[k].template head<Dim>() = advance(nodes[k], old ? old + k : nullptr);
      },
      [&](Node& node, const IVec& idx, Vec* old) {
        if (node[Dim] <= T(0)) return;
        Vec v = advance(node, old);
        for_each_grid_condition(idx, [&] { return Vec(origin_ + dx_ * idx.template cast<T>()); }, bc,
                                [&](const Vec& vb, const Vec& n, Condition c, T friction) {
                                  v = apply_condition<T, Dim>(v, vb, n, c, friction);
                                });
        node.template head<Dim>() = v;
      });
}

template <class T, int Dim>
template <class G>
void MpmSolver<T, Dim>::grid_to_particles(G& grid, T dt) {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: grid_to_particles_order<1>(grid, dt); break;
    case KernelKind::Quadratic: grid_to_particles_order<2>(grid, dt); break;
    case KernelKind::Cubic: grid_to_particles_order<3>(grid, dt); break;
  }
}

template <class T, int Dim>
template <int Order, class G>
void MpmSolver<T, Dim>::grid_to_particles_order(G& grid, T dt) {
  using transfer::Scheme;
  auto& P = particles_;
  const T flip = T(scene_.solver.flip_ratio);
  Mat* C = P.C.empty() ? nullptr : P.C.data();
  Mat* F = P.F.empty() ? nullptr : P.F.data();
  T* J = P.J.empty() ? nullptr : P.J.data();
  const auto& bins = bins_.bins();
  const std::uint32_t* order = bins_.order();
  const T inv_dx = T(1) / dx_;
  // A split run gathers the bins of its own block columns only. The test sits behind a
  // loop-invariant flag, which the compiler unswitches: the one-process loop stays as it was
  // (testing bounds in every bin instead cost 2D G2P 30%, 5.9 -> 7.6 ms per step; a test through
  // split_ cost the same), and tests/mpi checks that the split copy computes the same bits.
  const bool split = bool(split_);
  const int axis = split ? split_->axis : 0, own_lo = split ? split_->lo : 0, own_hi = split ? split_->hi : 0;
  // F <- (I + dt grad v) F for solids, J <- det(I + dt grad v) J for fluids.
  // In lanes where the gather queues the updates (deformation_lanes.h); elsewhere the lambda, as
  // 2D G2P was tuned with: given the functor struct, GCC kept the 2D gather out of line and the
  // 2D mls88 benchmark was 7-9% slower.
  auto solid_state = [&] {
    if constexpr (detail::SolidStateUpdate<T, Dim>::kBatched) {
      return detail::SolidStateUpdate<T, Dim>{F, dt};
    } else {
      return [=](std::int64_t p, const Mat& gv) {
        const Mat A = Mat::Identity() + dt * gv;
        F[p] = A * F[p];
      };
    }
  }();
  auto fluid_state = [=](std::int64_t p, const Mat& gv) { J[p] *= (Mat::Identity() + dt * gv).determinant(); };
  auto gather = [&](auto scheme) {
    constexpr Scheme S = decltype(scheme)::value;
    if constexpr (S == Scheme::MLS && Order == 1) {
      return T(0);  // rejected by Scene::validate
    } else {
      return parallel::parallel_max<T>(
          0, std::int64_t(bins.size()), T(0),
          [&](std::int64_t lo, std::int64_t hi) {
            T r2 = 0;
            for (std::int64_t b = lo; b < hi; ++b) {
              if (sleep_ && sleep_->bin_block[std::size_t(b)]) continue;
              const auto& bin = bins[std::size_t(b)];
              if (split && (bin.block[axis] < own_lo || bin.block[axis] >= own_hi)) continue;  // ghosts: their rank moves them
              transfer::Patch<T, Dim, Order> patch(bin.block, origin_, dx_, inv_dx);
              grid.read_patch(patch);
              const T s2 = fluid_[bin.material]
                               ? transfer::gather_particles<Order, S>(patch, P.x.data(), P.v.data(), C, dt, flip, x_lo_,
                                                                      x_hi_, order, bin.begin, bin.end, fluid_state)
                               : transfer::gather_particles<Order, S>(patch, P.x.data(), P.v.data(), C, dt, flip, x_lo_,
                                                                      x_hi_, order, bin.begin, bin.end, solid_state);
              r2 = std::max(r2, s2);
            }
            return r2;
          },
          parallel::task_run(std::int64_t(bins.size())));
    }
  };
  T vmax2 = 0;
  switch (scene_.solver.transfer) {
    case TransferKind::PIC: vmax2 = gather(std::integral_constant<Scheme, Scheme::PIC>{}); break;
    case TransferKind::FLIP: vmax2 = gather(std::integral_constant<Scheme, Scheme::FLIP>{}); break;
    case TransferKind::APIC: vmax2 = gather(std::integral_constant<Scheme, Scheme::APIC>{}); break;
    case TransferKind::MLS: vmax2 = gather(std::integral_constant<Scheme, Scheme::MLS>{}); break;
  }
  max_speed_ = std::sqrt(vmax2);
  // A particle moving more than a cell in one substep (or non-finite, or outside the domain)
  // means the step was unstable: stop with a diagnosis rather than write garbage.
  const T limit = std::max(T(1), T(2 * scene_.solver.cfl)) * dx_;
  if (split_) {  // every rank stops, with the diagnosis of the first rank that found one
    const bool bad = !(max_speed_ * dt <= limit);
    double worst[2] = {bad ? 1.0 : 0.0, bad ? 0.0 : double(max_speed_)};
    split_->comm->max(worst, 2);
    if (worst[0] > 0) {
      for (const auto& why : split_->comm->all_gather(bad ? diagnosis(dt) : std::string()))
        if (!why.empty()) throw SimulationError(why);
    }
    max_speed_ = T(worst[1]);
  } else if (!(max_speed_ * dt <= limit)) {
    diagnose(dt);
  }
  cfl_reached_ = std::max(cfl_reached_, max_speed_ * dt / dx_);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::return_mapping() {
  auto& P = particles_;
  const auto& bins = bins_.bins();
  const std::uint32_t* order = bins_.order();
  bool snow = false;
  for (const auto& m : materials_) snow = snow || m.plastic_kind == PlasticModel::Snow;
  // Plastic projection per bin; for snow also the largest hardening factor, which stiffens the
  // material and so shortens its elastic time-step limit.
  std::vector<T>& hmax = hardening_scratch_;
  hmax.assign(snow ? bins.size() : 0, T(1));
  projected_scratch_.assign(bins.size(), 0);
  parallel::parallel_task_runs(0, std::int64_t(bins.size()), [&](std::int64_t bi) {
    const auto& bin = bins[std::size_t(bi)];
    const auto& mat = materials_[bin.material];
    if (mat.plastic_kind == PlasticModel::None || project_in_p2g_[bin.material] || !owned_block(bin.block)) return;
    if (sleep_ && sleep_->bin_block[std::size_t(bi)]) {  // unchanged since it fell asleep
      if (snow) hmax[std::size_t(bi)] = sleep_->bin_block[std::size_t(bi)]->hardening;
      return;
    }
    // Snow's hardening factor min(exp(xi (1 - Jp)), cap) does not grow with Jp (exp and the
    // rounding of xi (1 - Jp) are monotonic): the bin's largest is the factor of its smallest Jp,
    // one exp per bin instead of one per particle. A NaN Jp is skipped by std::min as its factor
    // was by std::max.
    T jp_min = std::numeric_limits<T>::infinity();
    std::int64_t yielded = 0;
    if (mat.plastic_kind == PlasticModel::Snow) {  // the window tests 16 particles at a time
      constexpr int W = 16;
      bool inside[W];
      for (auto i = bin.begin; i < bin.end; i += W) {
        const int n = int(std::min<std::int64_t>(W, std::int64_t(bin.end) - std::int64_t(i)));
        mat.snow.template inside_windows<Dim, W>(P.F.data(), order + i, n, inside);
        for (int k = 0; k < n; ++k) {
          const auto p = order[i + k];
          if (!inside[k]) yielded += mat.snow.project_by_svd(P.F[p], P.plastic[p]);
          jp_min = std::min(jp_min, P.plastic[p]);
        }
      }
    } else {
      for (auto i = bin.begin; i < bin.end; ++i) {
        const auto p = order[i];
        yielded += mat.project(P.F[p], P.plastic[p]);
        jp_min = std::min(jp_min, P.plastic[p]);
      }
    }
    projected_scratch_[std::size_t(bi)] = yielded;
    if (mat.plastic_kind == PlasticModel::Snow)  // then `snow` holds and hmax is sized
      hmax[std::size_t(bi)] = std::max(T(1), mat.hardening_factor(jp_min));
  });
  for (const auto n : projected_scratch_) projected_ += n;
  if (snow) {
    for (auto& m : materials_)
      if (m.plastic_kind == PlasticModel::Snow) m.wave_speed = m.base_wave_speed;
    for (std::size_t bi = 0; bi < bins.size(); ++bi) {
      auto& m = materials_[bins[bi].material];
      if (m.plastic_kind == PlasticModel::Snow)
        m.wave_speed = std::max(m.wave_speed, m.base_wave_speed * std::sqrt(hmax[bi]));
    }
  }
  const bool fluid = fluid_wave_speeds();
  if (split_ && (snow || fluid)) {  // the time step is global: the stiffest snow or liquid of any rank
    std::vector<double> c;
    for (const auto& m : materials_) c.push_back(double(m.wave_speed));
    split_->comm->max(c.data(), int(c.size()));
    for (std::size_t k = 0; k < c.size(); ++k) materials_[k].wave_speed = T(c[k]);
  }
  max_wave_speed_ = 0;
  for (const auto& m : materials_) max_wave_speed_ = std::max(max_wave_speed_, m.wave_speed);
}

template <class T, int Dim>
bool MpmSolver<T, Dim>::fluid_wave_speeds() {
  // A Tait liquid stiffens as it is compressed: c(J) = c(1) J^((1-gamma)/2) (fluid.h). Where a
  // liquid hits a wall it reaches J = 0.8 and below, c(J) is nearly twice c(1), and a step set by
  // c(1) alone would run at an elastic Courant number near 1 there and blow up. So each fluid's
  // wave speed is taken at the extremes of J that its particles reached in this substep; since
  // c(J) is monotonic in J, the smallest and the largest J bound it.
  bool any = false;
  for (const auto& m : materials_) any = any || m.fluid;
  if (!any) return false;
  const auto& P = particles_;
  const auto& bins = bins_.bins();
  const std::uint32_t* order = bins_.order();
  auto& range = fluid_J_scratch_;
  range.assign(bins.size(), {std::numeric_limits<T>::max(), std::numeric_limits<T>::lowest()});
  parallel::parallel_task_runs(0, std::int64_t(bins.size()), [&](std::int64_t bi) {
    const auto& bin = bins[std::size_t(bi)];
    if (!fluid_[bin.material] || !owned_block(bin.block)) return;
    T lo = std::numeric_limits<T>::max(), hi = std::numeric_limits<T>::lowest();
    for (auto i = bin.begin; i < bin.end; ++i) {
      const T J = P.J[order[i]];
      lo = std::min(lo, J);
      hi = std::max(hi, J);
    }
    range[std::size_t(bi)] = {lo, hi};
  });
  for (auto& m : materials_)
    if (m.fluid) m.wave_speed = m.base_wave_speed;
  for (std::size_t bi = 0; bi < bins.size(); ++bi) {
    auto& m = materials_[bins[bi].material];
    if (!m.fluid || range[bi].first > range[bi].second) continue;
    const auto& eos = m.fluid_model();
    const T ratio = std::max(eos.sound_speed_ratio(range[bi].first), eos.sound_speed_ratio(range[bi].second));
    m.wave_speed = std::max(m.wave_speed, m.base_wave_speed * ratio);
  }
  return true;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::sleep_prepare() {
  auto& S = *sleep_;
  const auto& bins = bins_.bins();
  const std::size_t groups = bins_.groups();
  S.group_block.assign(groups, nullptr);
  S.bin_block.assign(bins.size(), nullptr);
  for (std::size_t g = 0; g < groups; ++g) {
    const auto first = bins_.group_begin(g), last = bins_.group_begin(g + 1);
    const auto it = S.asleep.find(bins_.group_key(g));
    if (it == S.asleep.end()) continue;
    std::uint32_t count = 0;
    for (auto b = first; b < last; ++b) count += bins[b].end - bins[b].begin;
    if (count != it->second.count) {  // a particle came in (or went): the block is not at rest
      S.asleep.erase(it);
      ++S.woken;
      continue;
    }
    S.group_block[g] = &it->second;
    for (auto b = first; b < last; ++b) S.bin_block[b] = &it->second;
  }
}

template <class T, int Dim>
template <int Order, class G>
void MpmSolver<T, Dim>::sleep_wake(G& grid) {
  auto& S = *sleep_;
  if (S.asleep.empty()) return;
  const auto& bins = bins_.bins();
  const std::size_t groups = bins_.groups();
  const T wake2 = S.wake * S.wake;
  // A sleeping block wakes when a node its particles reach moves faster than the wake speed
  // after the grid update: something hit it, a collider came near, or its support moved.
  std::vector<std::uint8_t> wake(groups, 0);
  parallel::parallel_tasks(0, std::int64_t(groups), [&](std::int64_t g) {
    if (!S.group_block[std::size_t(g)]) return;
    transfer::Patch<T, Dim, Order> patch(bins[bins_.group_begin(std::size_t(g))].block, origin_, dx_, T(1) / dx_);
    grid.read_patch(patch);
    for (const auto& node : patch.nodes)
      if (node[Dim] > T(0) && node.template head<Dim>().squaredNorm() > wake2) {
        wake[std::size_t(g)] = 1;
        return;
      }
  });
  for (std::size_t g = 0; g < groups; ++g) {
    if (!wake[g]) continue;
    S.asleep.erase(bins_.group_key(g));
    ++S.woken;
    S.group_block[g] = nullptr;
    for (auto b = bins_.group_begin(g); b < bins_.group_begin(g + 1); ++b) S.bin_block[b] = nullptr;
  }
}

template <class T, int Dim>
void MpmSolver<T, Dim>::sleep_update() {
  auto& S = *sleep_;
  auto& P = particles_;
  const auto& bins = bins_.bins();
  const std::uint32_t* order = bins_.order();
  const std::size_t groups = bins_.groups();
  const T speed2 = S.speed * S.speed, rate2 = S.rate * S.rate;
  // Calm: every particle of the block slower than `speed` and deforming slower than `rate`.
  S.group_calm.assign(groups, 0);
  parallel::parallel_tasks(0, std::int64_t(groups), [&](std::int64_t g) {
    if (S.group_block[std::size_t(g)]) return;
    for (auto b = bins_.group_begin(std::size_t(g)); b < bins_.group_begin(std::size_t(g) + 1); ++b)
      for (auto i = bins[b].begin; i < bins[b].end; ++i) {
        const auto p = order[i];
        if (P.v[p].squaredNorm() > speed2 || (!P.C.empty() && P.C[p].squaredNorm() > rate2)) return;
      }
    S.group_calm[std::size_t(g)] = 1;
  });
  for (std::size_t g = 0; g < groups; ++g) {
    if (S.group_block[g]) continue;
    const auto first = bins_.group_begin(g), last = bins_.group_begin(g + 1);
    const std::int64_t k = bins_.group_key(g);
    const std::size_t ks = std::size_t(k);
    const int before = S.seen[ks] == steps_ - 1 ? int(S.calm[ks]) : 0;  // steps_ is this substep's index
    S.seen[ks] = steps_;
    S.calm[ks] = std::uint16_t(S.group_calm[g] ? std::min(before + 1, 65535) : 0);
    if (S.calm[ks] < S.substeps) continue;
    // Fall asleep: the particles stop where they are. A material whose return mapping runs in
    // P2G gets it now: the block's cached contribution is built from the projected F.
    typename SleepState::Block blk;
    for (auto b = first; b < last; ++b) {
      const auto& mat = materials_[bins[b].material];
      const bool project = project_in_p2g_[bins[b].material];
      for (auto i = bins[b].begin; i < bins[b].end; ++i) {
        const auto p = order[i];
        if (project) projected_ += mat.project(P.F[p], P.plastic[p]);
        P.v[p].setZero();
        if (!P.C.empty()) P.C[p].setZero();
        if (mat.plastic_kind == PlasticModel::Snow) blk.hardening = std::max(blk.hardening, mat.hardening_factor(P.plastic[p]));
      }
      blk.count += bins[b].end - bins[b].begin;
    }
    S.asleep.emplace(k, std::move(blk));
    S.calm[ks] = 0;
    ++S.slept;
  }
}

template <class T, int Dim>
void MpmSolver<T, Dim>::diagnose(T dt) const {
  throw SimulationError(diagnosis(dt));
}

template <class T, int Dim>
std::string MpmSolver<T, Dim>::diagnosis(T dt) const {
  const auto& P = particles_;
  const T limit = std::max(T(1), T(2 * scene_.solver.cfl)) * dx_;
  std::int64_t worst = -1;
  std::string what;
  T worst_speed = -1;
  const std::int64_t n = std::int64_t(split_ ? split_->owned : P.size());  // not a split run's ghosts
  for (std::int64_t p = 0; p < n && what.empty(); ++p) {
    if (!P.x[p].allFinite() || !P.v[p].allFinite()) {
      worst = p, what = "has a non-finite position or velocity";
    } else if ((P.x[p].array() < x_lo_.array()).any() || (P.x[p].array() > x_hi_.array()).any()) {
      worst = p, what = "left the domain (grid plus one cell)";
    } else if (P.v[p].norm() > worst_speed) {
      worst = p, worst_speed = P.v[p].norm();
    }
  }
  if (what.empty())
    what = "moved " + detail::fmt(double(worst_speed * dt / dx_)) + " cells in one substep (speed " +
           detail::fmt(double(worst_speed)) + " m/s, dt " + detail::fmt(double(dt)) + " s; limit " +
           detail::fmt(double(limit / dx_)) + " cells): CFL violation";
  const int mat = worst >= 0 && !P.material.empty() ? int(P.material[std::size_t(worst)]) : 0;
  const std::int64_t id = worst >= 0 ? std::int64_t(P.id[std::size_t(worst)]) : -1;
  std::ostringstream msg;
  msg << scene_.source << ": simulation unstable at step " << steps_ + 1 << ", t = " << detail::fmt(time_ + double(dt))
      << " s: particle " << id << " (material \"" << scene_.materials[mat].name << "\") " << what;
  if (cg_.unconverged > 0)
    msg << " (the implicit CG solve missed solver.cg_tolerance in " << cg_.unconverged << " of " << cg_.solves
        << " substeps; try a larger solver.cg_max_iterations)";
  msg << ". No further frames are written. Try a smaller solver.cfl, solver.elastic_cfl or solver.max_dt"
      << ", or a stiffer boundary.";
  return msg.str();
}

template <class T, int Dim>
T MpmSolver<T, Dim>::kinetic_energy() const {
  const T* m = particles_.m.read_base();
  const std::size_t mask = particles_.m.read_mask();
  T e = 0;
  for (std::size_t p = 0; p < particles_.size(); ++p)
    e += T(0.5) * m[p & mask] * particles_.v[p].squaredNorm();
  return e;
}

template <class T, int Dim>
T MpmSolver<T, Dim>::elastic_energy() const {
  const auto& P = particles_;
  const T* vol0 = P.vol0.read_base();
  const std::size_t mask = P.vol0.read_mask();
  T e = 0;
  for (std::size_t p = 0; p < P.size(); ++p) {
    const auto& mat = materials_[P.material.empty() ? 0 : P.material[p]];
    if (mat.fluid) continue;
    mat.visit_elastic([&](const auto& model) { e += vol0[p & mask] * model.energy(P.F[p]); });
  }
  return e;
}

template <class T, int Dim>
RunStats MpmSolver<T, Dim>::take_stats() {
  const auto& P = particles_;
  RunStats s;
  s.time = time_;
  s.particles = P.size();
  add_particle_sums(s, P.x, P.v, P.m.per_particle(), double(P.m.value()), scene_.solver.gravity);
  s.elastic = double(elastic_energy());
  const T* vol0 = P.vol0.read_base();
  const std::size_t mask = P.vol0.read_mask();
  for (std::size_t p = 0; p < P.size(); ++p) {
    const bool fluid = detail::tracks_J(P, materials_, p);
    const double J = fluid ? double(P.J[p]) : double(P.F[p].determinant());
    s.volume += double(vol0[p & mask]) * J;
    if (fluid) s.max_fluid_J_error = std::max(s.max_fluid_J_error, std::abs(J - 1));
  }
  s.projected = projected_;
  s.cfl = double(cfl_reached_);
  projected_ = 0;
  cfl_reached_ = 0;
  if (split_) {  // the sums of every rank (in another order than one process: the last digits may differ)
    double sums[] = {s.mass, s.momentum[0], s.momentum[1], s.momentum[2], s.angular_momentum[0], s.angular_momentum[1],
                     s.angular_momentum[2], s.kinetic, s.potential, s.elastic, s.volume, double(s.particles),
                     double(s.projected)};
    split_->comm->sum(sums, int(std::size(sums)));
    s.mass = sums[0];
    s.momentum = {sums[1], sums[2], sums[3]};
    s.angular_momentum = {sums[4], sums[5], sums[6]};
    s.kinetic = sums[7], s.potential = sums[8], s.elastic = sums[9], s.volume = sums[10];
    s.particles = std::size_t(sums[11]);
    s.projected = std::int64_t(sums[12]);
    split_->comm->max(&s.max_fluid_J_error, 1);  // cfl is global already (max_speed_ is)
  }
  return s;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::save_state(const StateSink& out) const {
  // Between substeps the grid, the bins and the stress are scratch (rebuilt by every substep);
  // what carries over is the particles in their storage order (the periodic re-sort depends on
  // steps_), the step and time, the speed and wave-speed limits of the next stable_dt() (snow
  // hardening raises a material's wave speed), and the counters of take_stats().
  // A split run writes every rank's particles (on every rank): a checkpoint resumes on any
  // number of processes, since the bins order particles by id, not by storage.
  detail::StateWriter w(out);
  detail::write_layout<T, Dim>(w, detail::kTagMpm);
  Particles<T, Dim> all;
  if (split_) all = all_particles(true);
  const auto& P = split_ ? all : particles_;
  w.pod(P.channels);
  w.vec(P.x);
  w.vec(P.v);
  // Mass and rest volume are written per particle, also while stored once (the file format
  // predates that); load_state stores them once again when they are all equal.
  detail::write_scalar_channel(w, P.m, P.size());
  detail::write_scalar_channel(w, P.vol0, P.size());
  w.vec(P.F);
  w.vec(P.J);
  w.vec(P.C);
  w.vec(P.plastic);
  w.vec(P.material);
  w.vec(P.id);
  w.pod(time_);
  w.pod(steps_);
  w.pod(max_speed_);
  w.pod(max_wave_speed_);
  w.pod(std::uint64_t(materials_.size()));
  for (const auto& m : materials_) w.pod(m.wave_speed);
  w.pod(projected_);
  w.pod(cfl_reached_);
  w.pod(cg_.last_iterations);
  w.pod(cg_.last_residual);
  w.pod(cg_.solves);
  w.pod(cg_.iterations);
  w.pod(cg_.unconverged);
  if (sleep_) {  // only scenes with solver.sleep carry it (same scene hash on resume)
    const auto& S = *sleep_;
    w.vec(S.calm);
    w.vec(S.seen);
    std::vector<std::int64_t> keys;
    for (const auto& [k, blk] : S.asleep) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    w.pod(std::uint64_t(keys.size()));
    for (const auto k : keys) {
      const auto& blk = S.asleep.at(k);
      w.pod(k);
      w.pod(blk.count);
      w.pod(blk.hardening);
    }
    w.pod(S.woken);
    w.pod(S.slept);
  }
  w.tag(detail::kTagEnd);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::load_state(std::string_view in, const std::string& what) {
  detail::StateReader r(in, what);
  detail::read_layout<T, Dim>(r, detail::kTagMpm, "MPM");
  auto& P = particles_;
  const Channels c = r.get<Channels>();
  if (c.F != P.channels.F || c.J != P.channels.J || c.C != P.channels.C || c.plastic != P.channels.plastic ||
      c.material != P.channels.material)
    r.fail("its particles carry other channels (F, J, C, plastic, material) than this scene's materials and transfer need");
  r.vec(P.x, -1, "x");
  const auto n = std::int64_t(P.x.size());
  r.vec(P.v, n, "v");
  detail::read_scalar_channel(r, P.m, n, "m");
  detail::read_scalar_channel(r, P.vol0, n, "vol0");
  r.vec(P.F, c.F ? n : 0, "F");
  r.vec(P.J, c.J ? n : 0, "J");
  r.vec(P.C, c.C ? n : 0, "C");
  r.vec(P.plastic, c.plastic ? n : 0, "plastic");
  r.vec(P.material, c.material ? n : 0, "material");
  r.vec(P.id, n, "id");
  for (const auto k : P.material)
    if (k >= materials_.size()) r.fail("a particle's material " + std::to_string(k) + " is not one of this scene's");
  detail::require_inside(r, P.x, x_lo_, x_hi_);
  detail::require_finite(r, P.v, "the velocity");
  for (std::int64_t p = 0; p < n; ++p)
    if (!(P.m[std::size_t(p)] > T(0) && std::isfinite(P.m[std::size_t(p)]) && P.vol0[std::size_t(p)] > T(0) &&
          std::isfinite(P.vol0[std::size_t(p)])))
      r.fail("the mass or rest volume of particle " + std::to_string(p) + " is not a finite value > 0");
  detail::require_finite(r, P.F, "F");
  detail::require_positive(r, P.J, "J");
  detail::require_finite(r, P.C, "C");
  detail::require_finite(r, P.plastic, "the plastic state");
  detail::require_unique_ids(r, P.id, std::uint64_t(n));  // an MPM frame's row is its particle's id
  r.pod(time_);
  if (!(time_ >= 0 && std::isfinite(time_))) r.fail("its time is not a finite value >= 0");
  r.pod(steps_);
  r.pod(max_speed_);
  r.pod(max_wave_speed_);
  if (r.get<std::uint64_t>() != materials_.size()) r.fail("it has another number of materials");
  for (auto& m : materials_) r.pod(m.wave_speed);
  r.pod(projected_);
  r.pod(cfl_reached_);
  r.pod(cg_.last_iterations);
  r.pod(cg_.last_residual);
  r.pod(cg_.solves);
  r.pod(cg_.iterations);
  r.pod(cg_.unconverged);
  if (sleep_) {
    auto& S = *sleep_;
    r.vec(S.calm, std::int64_t(S.calm.size()), "sleep calm counts");
    r.vec(S.seen, std::int64_t(S.seen.size()), "sleep steps");
    S.asleep.clear();
    const auto blocks = r.get<std::uint64_t>();
    if (blocks > S.calm.size()) r.fail("it has more sleeping blocks than the grid has blocks");
    for (std::uint64_t i = 0; i < blocks; ++i) {
      const auto k = r.get<std::int64_t>();
      if (k < 0 || std::uint64_t(k) >= S.calm.size()) r.fail("a sleeping block lies outside the grid");
      typename SleepState::Block blk;
      r.pod(blk.count);
      r.pod(blk.hardening);
      S.asleep.emplace(k, std::move(blk));  // its grid contribution is scattered again (cached = false)
    }
    r.pod(S.woken);
    r.pod(S.slept);
  }
  r.tag(detail::kTagEnd, "end");
  r.finish();
  if (split_) {
    split_->total = P.size();
    split_particles();
  }
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::frame(const std::vector<std::string>& attributes) const {
  if (!split_) return frame_of(particles_, attributes);
  // Gathered on rank 0, which writes the frame; kept there for particle_storage().
  auto& gathered = split_->gathered;
  gathered = all_particles(false);
  return split_->comm->rank() == 0 ? frame_of(gathered, attributes) : Frame{};
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::own_frame(const std::vector<std::string>& attributes) const {
  if (!split_) return frame(attributes);
  // This process's particles in ascending id: row r holds the r-th smallest id it owns.
  const auto& P = particles_;
  std::vector<std::uint32_t> order(P.size()), rows(P.size());
  for (std::size_t p = 0; p < order.size(); ++p) order[p] = std::uint32_t(p);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return P.id[a] < P.id[b]; });
  for (std::size_t r = 0; r < order.size(); ++r) rows[order[r]] = std::uint32_t(r);
  const bool requested = std::find(attributes.begin(), attributes.end(), "id") != attributes.end();
  std::vector<std::string> columns = attributes;
  if (!requested) columns.push_back("id");
  Frame part = frame_of(P, columns, rows.data());
  part.comments.push_back("slurry part " + std::to_string(split_->comm->rank()) + " of " +
                          std::to_string(split_->comm->size()) + (requested ? " id=requested" : " id=added"));
  return part;
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::frame_of(const Particles<T, Dim>& P, const std::vector<std::string>& attributes,
                                         const std::uint32_t* rows) const {
  // Particles are stored in bin order; frames list them in seeding order (P.id).
  detail::VertexFrame out("", time_, scene_.source, P.size(), rows ? rows : P.id.data());
  for (const auto& a : attributes) {
    if (a == "position") {
      out.add_positions<Dim>(P.x);
    } else if (a == "velocity") {
      out.add_velocities<Dim>(P.v);
    } else if (a == "material") {
      out.add("material", [&](std::size_t p) { return P.material.empty() ? std::uint16_t(0) : P.material[p]; });
    } else if (a == "J") {
      out.add("J", [&](std::size_t p) {
        return detail::tracks_J(P, materials_, p) ? P.J[p] : T(P.F[p].determinant());
      });
    } else if (a == "plastic") {
      out.add("plastic", [&](std::size_t p) { return P.plastic.empty() ? T(0) : P.plastic[p]; });
    } else if (a == "id") {
      out.add("id", [&](std::size_t p) { return P.id[p]; });  // = the row: MPM keeps every particle
    }
  }
  return std::move(out.data());
}

template <class T, int Dim>
ParticleStorage MpmSolver<T, Dim>::particle_storage() const {
  // A split run's rank 0 shows every particle as of the last frame(); other ranks their own.
  const auto& P = split_ && split_->comm->rank() == 0 ? split_->gathered : particles_;
  ParticleStorage s;
  s.precision = std::is_same_v<T, double> ? Precision::Double : Precision::Float;
  s.dimension = Dim;
  s.count = P.size();
  s.x = P.x.data();
  s.v = P.v.data();
  s.id = P.id.data();
  if (!P.material.empty()) s.material = P.material.data();
  if (!P.F.empty()) s.F = P.F.data();
  if (!P.J.empty()) s.J = P.J.data();
  if (!P.plastic.empty()) s.plastic = P.plastic.data();
  return s;
}

}  // namespace slurry
