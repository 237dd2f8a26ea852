// Definition of FlipSolver<T, Dim>; included by one translation unit per (T, Dim).
#pragma once
#include <type_traits>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <ctime>
#include <sstream>
#include <string>

#include "flip/split.h"
#include "frame_builder.h"
#include "geometry/scene_meshes.h"
#include "state_io.h"
#include "slurry/engine/flip/advection.h"
#include "slurry/engine/flip/extrapolate.h"
#include "slurry/engine/flip/face_transfer.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/flip/level_set.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// to = from for each axis' face array, in parallel chunks.
template <class T, std::size_t N>
void copy_faces(const std::array<std::vector<T>, N>& from, std::array<std::vector<T>, N>& to) {
  for (std::size_t d = 0; d < N; ++d) {
    to[d].resize(from[d].size());
    const T* u = from[d].data();
    T* o = to[d].data();
    parallel::parallel_chunks(0, std::int64_t(from[d].size()), [&](std::int64_t lo, std::int64_t hi) {
      std::copy(u + lo, u + hi, o + lo);
    });
  }
}

namespace detail {
/// Seed of the reseeding generator (with the step number and the cell index).
constexpr std::uint64_t kReseedSeed = 0x5EEDF11Bull;
}  // namespace detail

template <class T, int Dim>
FlipSolver<T, Dim>::FlipSolver(const Scene& scene, Communicator* communicator) : scene_(scene) {
  scene_.validate();
  if (scene_.solver.type != SolverType::FLIP)
    throw SceneError(scene_.source + ": solver.type: FlipSolver needs \"flip\", got \"" +
                     std::string(to_string(scene_.solver.type)) + "\"");
  const auto& dom = scene_.domain;
  const T dx = T(dom.dx);
  IVec res;
  for (int d = 0; d < Dim; ++d) res[d] = int(std::ceil((dom.max[d] - dom.min[d]) / dom.dx - 1e-9));
  const Vec origin = dom.min.head<Dim>().template cast<T>();
  solids_.colliders = slurry::detail::make_colliders<T, Dim>(scene_);
  grid_.resize(res, dx, origin, !solids_.empty());  // weight and u_solid only with colliders
  const T margin = T(1e-3) * dx;
  x_lo_ = origin.array() + margin;
  x_hi_ = (origin + dx * res.template cast<T>()).array() - margin;
  gravity_ = scene_.solver.gravity.head<Dim>().template cast<T>();
  order_ = scene_.solver.kernel == KernelKind::Linear ? 1 : 2;
  switch (scene_.solver.transfer) {
    case TransferKind::PIC: scheme_ = FaceScheme::PIC; break;
    case TransferKind::FLIP: scheme_ = FaceScheme::FLIP; break;
    default: scheme_ = FaceScheme::APIC; break;
  }
  const auto& pp = scene_.solver.pressure;
  projection_options_.preconditioner = pp.preconditioner == PressurePreconditioner::Multigrid ? Preconditioner::Multigrid
                                       : pp.preconditioner == PressurePreconditioner::MIC0   ? Preconditioner::MIC0
                                       : pp.preconditioner == PressurePreconditioner::Jacobi ? Preconditioner::Jacobi
                                                                                             : Preconditioner::None;
  projection_options_.tolerance = pp.tolerance;
  projection_options_.max_iterations = pp.max_iterations;
  projection_options_.density = scene_.materials[0].density;
  for (const auto& m : scene_.materials) {
    material_mu_.push_back(T(m.viscosity));
    viscous_ = viscous_ || m.viscosity > 0;
    mixed_viscosity_ = mixed_viscosity_ || m.viscosity != scene_.materials[0].viscosity;
  }
  viscosity_.no_slip_walls = scene_.boundaries.walls == Condition::Sticky;
  sigma_ = T(scene_.materials[0].surface_tension);
  const FreeSurface surface = scene_.solver.free_surface;
  subcell_surface_ = surface == FreeSurface::Subcell || (surface == FreeSurface::Auto && (sigma_ > T(0) || viscous_));
  pressure_.set_subcell_surface(subcell_surface_);

  // The nominal density of particles: the densest body or emitter.
  double ppc = 0;
  for (const auto& b : scene_.bodies) ppc = std::max(ppc, b.particles_per_cell);
  for (const auto& e : scene_.emitters) ppc = std::max(ppc, e.particles_per_cell);
  particle_volume_ = T(std::pow(dom.dx, Dim) / ppc);
  particle_radius_ = T(0.5 * dom.dx / std::pow(ppc, 1.0 / Dim));

  auto& P = particles_;
  P.affine = scheme_ == FaceScheme::APIC;
  P.has_material = scene_.materials.size() > 1;
  for (std::size_t bi = 0; bi < scene_.bodies.size(); ++bi) {
    const auto& b = scene_.bodies[bi];
    std::vector<Vec> xs;
    if constexpr (Dim == 3) {
      if (b.shape == Shape::Mesh) {
        double cell_volume = 0;
        for (const auto& x : slurry::detail::seed_mesh_body(scene_, bi, cell_volume)) xs.push_back(x.template cast<T>());
      }
    }
    if (b.shape != Shape::Mesh) xs = seed_body<T, Dim>(b, dom.dx);
    if (xs.empty())
      throw SceneError(scene_.source + ": bodies[" + std::to_string(bi) +
                       "]: seeds no particles (expected a body larger than the particle spacing)");
    const Vec v = b.velocity.head<Dim>().template cast<T>();
    const auto mat = std::uint16_t(scene_.material_index(b.material));
    for (const auto& x : xs) P.push_back(solids_.push_out(x, T(0), x_lo_, x_hi_, margin), v, mat);
  }
  for (const auto& e : scene_.emitters) emitters_.emplace_back(e, std::uint16_t(scene_.material_index(e.material)));
  if (scene_.solver.whitewater.enabled) whitewater_ = std::make_unique<Whitewater<T, Dim>>(scene_.solver.whitewater, gravity_);
  for (const auto& v : P.v) max_speed_ = std::max(max_speed_, v.norm());
  if (communicator && communicator->size() > 1) {
    // What the split does not carry yet is refused, by its scene key.
    const int ranks = communicator->size();
    std::string refused;
    if (viscous_) refused = "materials[].viscosity";
    else if (whitewater_ && scene_.output.per_rank) refused = "output.per_rank with solver.whitewater";
    else if (scene_.solver.on_instability == OnInstability::Retry) refused = "solver.on_instability \"retry\"";
    if (!refused.empty())
      throw SceneError(scene_.source + ": " + refused + ": a FLIP run split over " + std::to_string(ranks) +
                       " processes (mpirun -np " + std::to_string(ranks) +
                       ") does not support it yet; expected a liquid without viscosity, "
                       "with solver.on_instability \"stop\" and whitewater in gathered frames; "
                       "or mpirun -np 1");
    split_ = std::make_unique<detail::FlipSplit<T, Dim>>(communicator, res, origin, dx);
    split_particles();
  }
}

template <class T, int Dim>
FlipSolver<T, Dim>::~FlipSolver() = default;

template <class T, int Dim>
std::size_t FlipSolver<T, Dim>::particle_count() const {
  return split_ ? std::size_t(split_->total) : particles_.size();
}

template <class T, int Dim>
std::string FlipSolver<T, Dim>::solver_status() const {
  if (steps_ == 0) return {};
  const auto& r = last_projection_;
  char buf[192];
  std::snprintf(buf, sizeof buf, "pressure %s %d iterations, residual %.2g%s, max |div u| %.2g 1/s",
                split_ ? "CG (PETSc, BoomerAMG)" : "PCG", r.iterations, r.relative_residual,
                r.converged ? "" : " (not converged)", r.max_divergence);
  std::string status = buf;
  if (split_) {
    const auto& S = *split_;
    const double mean = double(S.total) / S.comm->size();
    std::string grid;
    for (int d = 0; d < Dim; ++d) grid += (d ? " x " : "") + std::to_string(S.boxes.procs[d]);
    std::snprintf(buf, sizeof buf, "; %d ranks in %s boxes: %.0f-%.0f particles per rank (imbalance %.3f), rank %d sent %.3g kB per substep to %d peers",
                  S.comm->size(), grid.c_str(), S.fewest, S.most, mean > 0 ? S.most / mean : 1.0, S.comm->rank(),
                  S.bytes_per_substep / 1e3, int(S.peers.size()));
    status += buf;
  }
  if (viscous_) {
    const auto& v = last_viscosity_;
    std::snprintf(buf, sizeof buf, "; viscosity PCG %d iterations, residual %.2g%s", v.iterations, v.relative_residual,
                  v.converged ? "" : " (not converged)");
    status += buf;
  }
  if (whitewater_) {
    const WhitewaterCounts c = whitewater_counts();
    std::snprintf(buf, sizeof buf, "; whitewater %zu spray, %zu foam, %zu bubbles", c.spray, c.foam, c.bubble);
    status += buf;
  }
  return status;
}

template <class T, int Dim>
std::size_t FlipSolver<T, Dim>::bytes() const {
  std::size_t b = particles_.bytes() + permute_spare_.bytes() +
                  (sort_.key.capacity() + sort_.order.capacity()) * sizeof(std::uint32_t) +
                  sort_.start.capacity() * sizeof(std::uint32_t);
  const std::size_t cells = std::size_t(grid_.num_cells());
  b += cells * (2 + 2 * sizeof(T)) + holes_.capacity();
  if (whitewater_) b += whitewater_->bytes();
  b += pressure_.bytes() + extrapolator_.bytes() + viscosity_.bytes() + surface_tension_.bytes() + cell_mu_.capacity() * sizeof(T);  // the pressure solve's vectors are most of the grid's memory
  for (int d = 0; d < Dim; ++d)
    b += (grid_.u[d].capacity() + grid_.weight[d].capacity() + grid_.u_solid[d].capacity() +
          weight_sum_[d].capacity() + old_u_[d].capacity() + pre_u_[d].capacity()) * sizeof(T) + grid_.valid[d].capacity();
  if (split_) {  // every rank's
    double all = double(b);
    split_->comm->sum(&all, 1);
    b = std::size_t(all);
  }
  return b;
}

template <class T, int Dim>
T FlipSolver<T, Dim>::advective_dt() const {
  T dt = T(scene_.solver.max_dt);
  if (max_speed_ > T(0)) dt = std::min(dt, T(scene_.solver.cfl) * grid_.dx / max_speed_);
  return dt;
}

template <class T, int Dim>
T FlipSolver<T, Dim>::stable_dt() const {
  T dt = advective_dt();
  if (sigma_ > T(0)) dt = std::min(dt, SurfaceTension<T, Dim>::max_dt(grid_.dx, density(), sigma_));
  return dt;
}

template <class T, int Dim>
std::int64_t FlipSolver<T, Dim>::advance_to(double t_end) {
  if (split_) rebalance();
  const std::uint64_t sent = split_ ? split_->comm->exchanged_bytes() : 0;
  const auto n = substep_to(time_, t_end, [&] { return dt_scale_ * double(stable_dt()); }, [&](double dt) { step(T(dt)); }, scene_);
  if (split_ && n > 0) split_->bytes_per_substep = double(split_->comm->exchanged_bytes() - sent) / double(n);
  if (split_ && whitewater_) count_split_whitewater();
  return n;
}

template <class T, int Dim>
void FlipSolver<T, Dim>::step(T dt) {
  using Clock = std::chrono::steady_clock;
  auto t0 = Clock::now();
  std::clock_t c0 = std::clock();
  const auto lap = [&](Phase p) {
    const auto t1 = Clock::now();
    const std::clock_t c1 = std::clock();
    phase_seconds_[p] += std::chrono::duration<double>(t1 - t0).count();
    phase_cpu_seconds_[p] += double(c1 - c0) / CLOCKS_PER_SEC;
    t0 = t1;
    c0 = c1;
  };
  emit(dt);
  if (split_) exchange_ghosts();
  lap(kEmit);
  sort_particles();
  lap(kSort);
  transfer_to_grid();
  lap(kToGrid);
  save_velocities();
  lap(kSave);
  apply_gravity(dt);
  lap(kGravity);
  build_boundaries(T(time_) + dt);
  if (split_) drop_ghosts();
  lap(kBoundaries);
  if (viscous_) apply_viscosity(dt);
  lap(kViscosity);
  project(dt);
  if (split_) {  // the window's faces as their owners projected them (split.h)
    auto& S = *split_;
    S.exchange_faces(grid_.u, S.band);
    S.exchange_faces(grid_.valid, S.band);
    S.exchange_faces(pre_u_, S.band);
    S.exchange_faces(weight_sum_, S.band);
  }
  lap(kProject);
  extrapolate_velocities(dt);
  lap(kExtrapolate);
  enforce_solids();
  if (split_) {  // the faces the particles read, as their owners extrapolated them
    split_->exchange_faces(grid_.u, split_->reach);
    if (scheme_ == FaceScheme::FLIP) split_->exchange_faces(old_u_, split_->reach);
  }
  lap(kEnforce);
  transfer_to_particles(dt);  // with the linear kernel, advection too (advects_in_g2p)
  lap(kToParticles);
  if (!advects_in_g2p()) advect(dt);
  if (split_) migrate();
  lap(kAdvect);
  cfl_reached_ = std::max(cfl_reached_, max_speed_ * dt / grid_.dx);
  reseed();
  lap(kReseed);
  if (whitewater_ && split_) split_whitewater(dt);
  else if (whitewater_) whitewater_->step(grid_, solids_, time_, dt, steps_, x_lo_, x_hi_);
  lap(kWhitewater);
  time_ += double(dt);
  ++steps_;
}

template <class T, int Dim>
void FlipSolver<T, Dim>::emit(T dt) {
  const std::size_t n0 = particles_.size();
  if (!split_) {
    for (auto& e : emitters_) e.emit(particles_, grid_, time_, double(dt));
  } else {
    // Every rank counts its own particles in the emitter's cells, the counts are summed, and
    // every rank draws the same new particles (the same ids); each keeps those it owns.
    auto& S = *split_;
    Grid domain;
    domain.res = S.res, domain.dx = S.dx, domain.origin = S.origin;
    const auto sum = [&S](std::vector<std::int32_t>& counts) {
      std::vector<double> c(counts.begin(), counts.end());
      S.comm->sum(c.data(), int(c.size()));
      for (std::size_t k = 0; k < c.size(); ++k) counts[k] = std::int32_t(c[k]);
    };
    for (auto& e : emitters_) e.emit(particles_, domain, time_, double(dt), sum);
  }
  const T margin = T(1e-3) * grid_.dx;
  for (std::size_t p = n0; p < particles_.size(); ++p)
    particles_.x[p] = solids_.push_out(particles_.x[p], T(time_), x_lo_, x_hi_, margin);
  if (split_ && particles_.size() > n0) {
    auto& S = *split_;
    const int me = S.comm->rank();
    std::size_t n = n0;
    for (std::size_t p = n0; p < particles_.size(); ++p)
      if (S.owner(particles_.x[p]) == me) particles_.move(n++, p);
    S.total += particles_.size() - n0;  // every rank added the same particles
    particles_.truncate(n);
    S.own = n;
  }
}

template <class T, int Dim>
void FlipSolver<T, Dim>::sort_particles() {
  sort_.build(particles_.x, grid_.origin, grid_.dx, grid_.res, true, grid_.offset);
  // The sort's keys are dead once `order` is built: their storage is the spare of the 32-bit
  // channel (the ids), and the ids' old storage holds the next sort's keys (4 bytes a particle).
  permute_spare_.u32.swap(sort_.key);
  particles_.permute(sort_.order, permute_spare_);
  sort_.key.swap(permute_spare_.u32);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::transfer_to_grid() {
  if (order_ == 1)
    particles_to_faces<1>(grid_, particles_, sort_, weight_sum_);
  else
    particles_to_faces<2>(grid_, particles_, sort_, weight_sum_);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::save_velocities() {
  if (scheme_ != FaceScheme::FLIP) return;
  copy_faces(grid_.u, old_u_);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::apply_gravity(T dt) {
  for (int d = 0; d < Dim; ++d) {
    const T dv = dt * gravity_[d];
    if (dv == T(0)) continue;
    T* u = grid_.u[d].data();
    parallel::parallel_chunks(0, std::int64_t(grid_.u[d].size()), [&](std::int64_t lo, std::int64_t hi) {
      for (std::int64_t f = lo; f < hi; ++f) u[f] += dv;
    });
  }
}

template <class T, int Dim>
void FlipSolver<T, Dim>::build_boundaries(T t) {
  // Without colliders the face weights (walls only) never change.
  if (!solids_.empty() || !faces_ready_) solids_.update_faces(grid_, t);
  faces_ready_ = true;
  label_cells(grid_, particles_, sort_, solids_, t, particle_radius_, holes_);
  if (subcell_surface_) place_surface_in_fluid_cells(grid_);  // solver.free_surface (level_set.h)
  if (sigma_ > T(0)) {
    surface_tension_.compute(grid_, particles_, sort_, sigma_, particles_per_cell());
    pressure_.set_surface_pressure(surface_tension_.pressure().data());
  }
}

template <class T, int Dim>
void FlipSolver<T, Dim>::apply_viscosity(T dt) {
  if (!mixed_viscosity_) {
    last_viscosity_ = viscosity_.solve(grid_, dt, scene_.materials[0].density, double(material_mu_[0]));
    return;
  }
  // Viscosity per cell: the mean over the cell's particles' materials; an empty cell (air next to
  // the liquid, or a hole) takes the largest of its 3^Dim neighbours', so that stress samples at
  // the surface see the liquid's viscosity.
  const std::int64_t cells = grid_.num_cells();
  cell_mu_.assign(std::size_t(cells), T(0));
  const std::uint32_t* start = sort_.start.data();
  const auto& mat = particles_.material;
  parallel::parallel_for(0, cells, [&](std::int64_t c) {
    const std::uint32_t p0 = start[c], p1 = start[c + 1];
    if (p1 == p0) return;
    T sum = T(0);
    for (std::uint32_t p = p0; p < p1; ++p) sum += material_mu_[mat[p]];
    cell_mu_[std::size_t(c)] = sum / T(p1 - p0);
  });
  std::vector<T>& filled = viscosity_scratch_;
  filled = cell_mu_;
  parallel::parallel_for(0, cells, [&](std::int64_t c) {
    if (start[c + 1] > start[c]) return;
    const IVec i = grid_.cell_coord(c);
    T mu = T(0);
    for (int o = 0; o < (Dim == 3 ? 27 : 9); ++o) {
      IVec q = i;
      bool inside = true;
      for (int d = 0, m = o; d < Dim; ++d, m /= 3) {
        q[d] += m % 3 - 1;
        inside = inside && q[d] >= 0 && q[d] < grid_.res[d];
      }
      if (!inside) continue;
      const std::int64_t k = grid_.cell(q);
      if (start[k + 1] > start[k]) mu = std::max(mu, cell_mu_[std::size_t(k)]);
    }
    filled[std::size_t(c)] = mu;
  });
  cell_mu_.swap(filled);
  last_viscosity_ = viscosity_.solve(grid_, dt, scene_.materials[0].density, 0.0, cell_mu_);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::project(T dt) {
  copy_faces(grid_.u, pre_u_);
  const double beta = scene_.solver.volume_correction;
  if (beta <= 0) {
    last_projection_ = split_ ? split_projection(dt, typename PressureSolver<T, Dim>::NoTarget{})
                              : pressure_.project(grid_, dt, projection_options_);
    return;
  }
  // Volume correction. Particles bunched by large steps (or squeezed against walls) carry more
  // liquid than their cells hold, and the discretely divergence-free grid velocity does not
  // spread them out again, so the liquid shrinks (40% of the 2D dam break's filled cells in 5 s
  // at one substep per frame). The particle density of a cell, relative to the seeding
  // density, is read from the face weight sums of the last P2G (sum_p w_pf, about
  // particles_per_cell on every face of a uniformly filled cell): rho_c = mean over the cell's
  // open faces / particles_per_cell. The projection then aims at
  // div u = beta (rho_c - 1) / dt instead of 0, which removes the share beta of the density
  // error in one step (the density constraint of Kugelstadt, Longva, Thuerey & Bender 2019,
  // "Implicit density projection for volume conserving liquids", IEEE TVCG 27(4), folded into
  // the one pressure solve as a divergence source). The error is clamped to [-0.5, 0.5]. In
  // surface cells (an air neighbour; under-filled by construction) only over-density counts,
  // and wall faces (closed, particles on one side only) are left out of the mean.
  const T ppc = particles_per_cell();
  // Dead band: |rho_c - 1| up to 0.3 is left alone. The estimate is noisy (jittered seeding,
  // few particles per face), and correcting that noise stirs a pool at rest (0.28 m/s after 2 s
  // in the hydrostatic test without the band, 0.0175 m/s with 0.1, at rest from 0.2 on).
  constexpr T kSlack = T(0.3);
  // The share beta is removed per advective step (max_dt or the CFL step), not per substep:
  // where the capillary limit makes the substep shorter (surface tension: 23 substeps per
  // max_dt of 1/240 s for water at dx = 0.5 mm), removing it every substep moved up to a
  // quarter of a cell's volume per substep into the sparse cells that the liquid's capillary
  // waves leave, kicks that a drop at rest took up as energy until it burst (a 2D disk at 45 s,
  // flip_surface_tension_tests).
  const double relax = sigma_ > T(0) ? std::max(double(dt), double(advective_dt())) : double(dt);
  const double flux_per_error = beta * double(grid_.dx) / relax;  // dx div u per unit density error
  // Evaluated by the projection at its unknowns (Fluid cells) only.
  std::int64_t cstride[Dim], fup[Dim];
  for (int d = 0; d < Dim; ++d) cstride[d] = grid_.cell_stride(d), fup[d] = grid_.face_stride(d, d);
  const std::uint8_t* label = grid_.label.data();
  const auto target_flux = [&](std::int64_t c, const IVec& i) {
    double target = 0;
    T w = 0;
    int open = 0;
    bool interior = true;
    // Open share of the cell's faces inside the domain (1 away from colliders): a cell that a
    // collider has nearly closed passes its target flux through slivers of faces, so the
    // target shrinks with them. Without this a mesh paddle sweeping through bunched liquid
    // drove the face velocity up as the substep shrank (the target grows as 1/dt), to 1e9 m/s.
    double openness = 0;
    int inner = 0;
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t lower = grid_.face(d, i);
      for (int side = 0; side < 2; ++side) {
        const int nd = i[d] + (side ? 1 : -1);  // neighbour cell's coordinate along d
        const std::int64_t nb = c + (side ? cstride[d] : -cstride[d]);
        if (nd >= 0 && nd < grid_.res[d] && label[nb] == Grid::Air) interior = false;
        const int fd = i[d] + side;  // the face's coordinate along d
        const std::int64_t f = lower + (side ? fup[d] : 0);
        const T open_w = grid_.open_weight(d, fd, f, side ? nb : c);
        if (fd > 0 && fd < grid_.res[d]) openness += double(open_w), ++inner;
        if (open_w <= T(0)) continue;  // a wall face sees particles on one side only
        w += weight_sum_[d][std::size_t(f)];
        ++open;
      }
    }
    if (open > 0) {
      const T e = w / (T(open) * ppc) - T(1);
      const T shrunk = e > kSlack ? e - kSlack : e < -kSlack ? e + kSlack : T(0);
      const T err = std::clamp(shrunk, interior ? T(-0.5) : T(0), T(0.5));
      target = flux_per_error * double(err);
      if (inner > 0 && openness < inner) target *= openness / inner;
    }
    return target;
  };
  last_projection_ = split_ ? split_projection(dt, target_flux) : pressure_.project(grid_, dt, projection_options_, target_flux);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::extrapolate_velocities(T dt) {
  // The faces with particle mass (a P2G weight) that the projection did not update (air on both
  // sides, next to the surface) keep their P2G velocity plus the projection's correction
  // extended from the projected faces, rather than a velocity extrapolated from those faces.
  // Overwriting the particles' own face velocities breaks the bound on kinetic energy that the
  // transfer round trip keeps (Jiang et al. 2015, sec. 5), and where particles stay in the same
  // cells over many substeps the gain compounds: two particles in diagonally adjacent cells,
  // zero gravity, dt = 1e-4 s, APIC, gained x1.12 kinetic energy per substep, and two 3 mm drops
  // merging at 0.185 ms substeps scattered their particles. The correction is added (not zero,
  // the pressure gradient between two air cells) so that a face just above a surface at rest
  // sees the pressure that holds the liquid up (the standing wave's period came out 7.5% long
  // with the P2G velocity alone). Elsewhere the extrapolated velocity is the better estimate (it
  // continues the divergence-free projected field; the kept one is not divergence free in the
  // air): where particles move more than a fraction of a cell per substep the cells they touch
  // change within a few substeps and the gain cannot compound. So the kept velocity is used in
  // full where the face's Courant number |u| dt / dx is below 0.1 (particles stay ten substeps
  // or more), the extrapolated one above 0.3 (kKeptNone), blended linearly over kBlend = 0.2
  // below it. With the blend from 1 to 2 instead, the 2D dam break at one substep per frame
  // lost more volume (mean worst drift 12.5%, 11.4% with this one) and the whitewater of a dam
  // break changed more when the substep was halved (count ratio 1.11, 1.09 with this one and
  // without kept faces).
  constexpr T kKeptNone = T(0.3), kBlend = T(0.2);
  const T nan = std::numeric_limits<T>::quiet_NaN();
  // The correction on the projected faces (NaN on the others), extended as a field of its own
  // in g.u's place over the faces a particle's kernel reaches from its cell's faces.
  for (int d = 0; d < Dim; ++d) {
    const T* u = grid_.u[d].data();
    const std::uint8_t* valid = grid_.valid[d].data();
    T* c = pre_u_[d].data();
    parallel::parallel_chunks(0, std::int64_t(grid_.u[d].size()), [&](std::int64_t lo, std::int64_t hi) {
      for (std::int64_t f = lo; f < hi; ++f) c[f] = valid[f] ? u[f] - c[f] : nan;
    });
    grid_.u[d].swap(pre_u_[d]);
  }
  extrapolator_.run(grid_, order_ + Dim - 1, Extrapolation::Constant, false);
  // pre_u_: the kept velocity on the unprojected faces with mass that the correction reached,
  // NaN on the others; g.u the projected velocities again. Closed faces (walls, solids) are
  // among them too; enforce_solids() sets them to the solid's velocity after this phase.
  for (int d = 0; d < Dim; ++d) {
    const T* u = pre_u_[d].data();
    const T* w = weight_sum_[d].data();
    const std::uint8_t* valid = grid_.valid[d].data();
    T* c = grid_.u[d].data();
    parallel::parallel_chunks(0, std::int64_t(grid_.u[d].size()), [&](std::int64_t lo, std::int64_t hi) {
      for (std::int64_t f = lo; f < hi; ++f) c[f] = !valid[f] && w[f] > T(0) ? u[f] + c[f] : nan;
    });
    grid_.u[d].swap(pre_u_[d]);
  }
  fill_air_velocities();
  const T courant = dt / grid_.dx;
  for (int d = 0; d < Dim; ++d) {
    const T* kept = pre_u_[d].data();
    T* u = grid_.u[d].data();
    parallel::parallel_chunks(0, std::int64_t(grid_.u[d].size()), [&](std::int64_t lo, std::int64_t hi) {
      for (std::int64_t f = lo; f < hi; ++f) {
        const T k = kept[f];
        if (std::isnan(k)) continue;
        const T share = std::clamp((kKeptNone - std::abs(k) * courant) / kBlend, T(0), T(1));
        u[f] = share * k + (T(1) - share) * u[f];
      }
    });
  }
}

template <class T, int Dim>
void FlipSolver<T, Dim>::fill_air_velocities() {
  // Particles read faces up to `reach` cfl cells (plus the kernel's reach) away from where
  // they start: the advection samples the grid at its stages' points (advection.h). Midpoint
  // samples only at x + dt/2 u(x), half a step away; Heun and RK3 at about a whole step
  // (x + dt k1; x - dt k1 + 2 dt k2 = x + dt u for a smooth u). On the 3D dam break (cfl 5)
  // midpoint's 5 layers instead of 7 give byte-identical frames, all 120 of them (RESULTS.md).
  const double reach = scene_.solver.advection == AdvectionScheme::Midpoint ? 0.5 : 1.0;
  const int layers = int(std::ceil(reach * scene_.solver.cfl)) + order_ + 1;
  extrapolator_.run(grid_, layers);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::enforce_solids() {
  // project() sets u = u_solid on closed faces and extrapolate() leaves them alone; without
  // colliders the closed faces are the walls, which only need their zero normal velocity.
  if (solids_.empty()) {
    for (int d = 0; d < Dim; ++d) {
      const auto fr = grid_.face_res(d);
      const std::int64_t outer = grid_.face_stride(d, d) * fr[d];  // faces per slab of axis d
      const std::int64_t slabs = grid_.num_faces(d) / outer;
      const std::int64_t stride = grid_.face_stride(d, d);
      parallel::parallel_for(0, slabs, [&](std::int64_t s) {
        T* u = grid_.u[d].data() + s * outer;
        std::fill(u, u + stride, T(0));
        std::fill(u + outer - stride, u + outer, T(0));
      });
    }
    return;
  }
  for (int d = 0; d < Dim; ++d)
    parallel::parallel_for(0, grid_.num_faces(d), [&](std::int64_t f) {
      if (grid_.open_weight(d, grid_.face_coord(d, f)) <= T(0)) grid_.u[d][f] = grid_.u_solid[d][f];
    });
}

template <class T, int Dim>
void FlipSolver<T, Dim>::transfer_to_particles(T dt) {
  const T ratio = T(scene_.solver.flip_ratio);
  const auto* old = scheme_ == FaceScheme::FLIP ? &old_u_ : nullptr;
  if (advects_in_g2p()) {
    const Advection adv(*this, dt);
    max_speed_ = faces_to_particles<1>(grid_, old, particles_, scheme_, ratio,
                                       [&adv](std::int64_t p, const Vec& u) { adv.particle(p, u); });
  } else {
    max_speed_ = faces_to_particles<2>(grid_, old, particles_, scheme_, ratio);
  }
  if (split_) {  // every rank's fastest particle; a non-finite one stops every rank
    double m = std::isfinite(double(max_speed_)) ? double(max_speed_) : std::numeric_limits<double>::infinity();
    split_->comm->max(&m, 1);
    max_speed_ = std::isfinite(m) ? T(m) : std::numeric_limits<T>::quiet_NaN();
  }
  if (!std::isfinite(double(max_speed_))) {
    std::ostringstream msg;
    msg << scene_.source << ": simulation unstable at step " << steps_ + 1 << ", t = " << slurry::detail::fmt(time_)
        << " s: a particle velocity became non-finite (last projection: " << last_projection_.iterations
        << " iterations, relative residual " << slurry::detail::fmt(last_projection_.relative_residual)
        << "). No further frames are written. Try a smaller solver.cfl or solver.max_dt.";
    throw SimulationError(msg.str());
  }
}

template <class T, int Dim>
FlipSolver<T, Dim>::Advection::Advection(FlipSolver& sim, T dt)
    : sim_(sim),
      dt_(dt),
      t0_(T(sim.time_)),
      t_end_(T(sim.time_) + dt),
      margin_(T(1e-3) * sim.grid_.dx),
      scheme_(sim.scene_.solver.advection),
      solids_(!sim.solids_.empty()),
      thin_(any_thin_collider(sim.solids_.colliders, sim.grid_.dx)),
      poses0_(collider_poses(sim.solids_.colliders, t0_)),
      poses1_(collider_poses(sim.solids_.colliders, t_end_)) {}

template <class T, int Dim>
typename FlipSolver<T, Dim>::Vec FlipSolver<T, Dim>::Advection::velocity(const Vec& x) const {
  Vec u;
  gather_faces_linear(sim_.grid_, x, nullptr, u, nullptr, nullptr);  // trilinear, flat indices
  return u;
}

template <class T, int Dim>
void FlipSolver<T, Dim>::Advection::particle(std::int64_t p, const Vec& k1) const {
  const Grid& g = sim_.grid_;
  auto& P = sim_.particles_;
  Vec x = advect_point(scheme_, P.x[p], k1, dt_, [this](const Vec& y) { return velocity(y); });
  // A collider thinner than the stencil (or any mesh) can be stepped over in one substep, or
  // its faces left open between grid nodes: a path that enters one stops at its surface.
  if (thin_) {
    const auto& colliders = sim_.solids_.colliders;
    for (std::size_t k = 0; k < colliders.size(); ++k) {
      const auto& c = colliders[k];
      Vec n;
      if (!thin_collider(c, g.dx) || !stop_at_collider(c, P.x[p], t0_, poses0_[k], x, t_end_, poses1_[k], margin_, n))
        continue;
      const T vn = (P.v[p] - c.velocity_at(x, t_end_)).dot(n);
      if (vn < T(0)) P.v[p] -= vn * n;
    }
  }
  P.x[p] = solids_ ? sim_.solids_.push_out(x, t_end_, sim_.x_lo_, sim_.x_hi_, margin_)
                   : Vec(x.cwiseMax(sim_.x_lo_).cwiseMin(sim_.x_hi_));
}

template <class T, int Dim>
void FlipSolver<T, Dim>::advect(T dt) {
  auto& P = particles_;
  const Advection adv(*this, dt);
  // The pass of the quadratic kernel (the linear one advects in G2P's pass, advects_in_g2p):
  // its G2P velocity is not the trilinear u(x_p) that advection integrates, so the first stage
  // is gathered here.
  parallel::parallel_chunks(0, std::int64_t(P.size()), [&](std::int64_t lo, std::int64_t hi) {
    for (std::int64_t p = lo; p < hi; ++p) adv.particle(p, adv.velocity(P.x[p]));
  });
}

template <class T, int Dim>
void FlipSolver<T, Dim>::reseed() {
  const auto& r = scene_.solver.reseed;
  if (r.min_per_cell <= 0 && r.max_per_cell <= 0) return;  // both off
  const Grid& g = grid_;
  const int order = order_;
  auto init = [&g, order](const Vec& x, Vec& v, Vec* c) {
    if (order == 1)
      gather_faces_linear(g, x, nullptr, v, nullptr, c);
    else
      gather_faces<2>(g, x, nullptr, v, nullptr, c);
  };
  typename Reseeder<T, Dim>::Window window;
  std::vector<double> window_counts;
  if (split_) {  // new particles only in the own cells, numbered over every rank (seeding.h)
    auto& S = *split_;
    window_counts = own_cell_counts(2);
    window.domain_res = S.res, window.lo = S.lo - S.wlo, window.hi = S.hi - S.wlo, window.counts = &window_counts;
    window.number = [&S, this](std::vector<std::pair<std::uint64_t, std::uint32_t>>& mine) {
      return S.number_new(mine, particles_.next_id);
    };
  }
  const auto counts = reseeder_.run(particles_, grid_, r.min_per_cell, r.max_per_cell, detail::kReseedSeed, steps_, init,
                                    split_ ? &window : nullptr);
  reseed_added_ += counts.added;
  reseed_removed_ += counts.removed;
}

template <class T, int Dim>
T FlipSolver<T, Dim>::kinetic_energy() const {
  T e = 0;
  for (const auto& v : particles_.v) e += v.squaredNorm();
  return T(0.5) * density() * particle_volume_ * e;
}

template <class T, int Dim>
RunStats FlipSolver<T, Dim>::take_stats() {
  // The area of the liquid's surface (surface tension's energy) over the cells `counted` accepts
  // (all if empty). Before the first substep no cell is labelled yet: the colliders' cells are
  // marked Solid for the area's mirrors (else the liquid's contact with them counts as surface),
  // then the labels are put back.
  const auto surface_area = [this](const std::function<bool(std::int64_t)>& counted) {
    std::vector<std::uint8_t> labels;
    if (steps_ == 0 && !solids_.empty()) {
      labels = grid_.label;
      for (std::int64_t k = 0; k < grid_.num_cells(); ++k)
        grid_.label[std::size_t(k)] = solids_.distance(grid_.cell_center(grid_.cell_coord(k)), T(time_)) < T(0) ? Grid::Solid : Grid::Air;
    }
    const double area = surface_tension_.area(grid_, particles_, particles_per_cell(), counted);
    if (!labels.empty()) grid_.label.swap(labels);
    return area;
  };
  RunStats s;
  s.time = time_;
  s.particles = particles_.size();
  const double m = double(density()) * double(particle_volume_);
  add_particle_sums(s, particles_.x, particles_.v, static_cast<const T*>(nullptr), m, scene_.solver.gravity);
  if (split_) {
    // The sums of every rank (in another order than one process: the last digits may differ),
    // and the volume from the counts of each rank's own cells, its ring's from their owners.
    auto& S = *split_;
    const std::vector<double> count = own_cell_counts();
    double interior = 0, held = 0;
    S.for_region(-1, S.lo, S.hi, [&](std::int64_t k) {
      if (count[std::size_t(k)] == 0) return;
      const IVec c = grid_.cell_coord(k), global = S.domain_cell(k);
      bool inside = true;
      for (int d = 0; d < Dim; ++d) inside = inside && global[d] > 0 && global[d] + 1 < S.res[d];
      for (int o = 0; inside && o < (Dim == 3 ? 27 : 9); ++o) {
        IVec q = c;
        for (int d = 0, mo = o; d < Dim; ++d, mo /= 3) q[d] += mo % 3 - 1;
        inside = count[std::size_t(grid_.cell(q))] > 0;
      }
      if (inside) interior += 1, held += count[std::size_t(k)];
    });
    double area = 0;
    if (sigma_ > T(0)) {
      // The colour function of the box's cells reads the particles around them: the ghosts for
      // the count, then dropped again (exchange_ghosts() appends them after the own particles).
      exchange_ghosts();
      area = surface_area([&S](std::int64_t k) { return S.in_box(S.domain_cell(k)); });
      particles_.truncate(S.own);
    }
    double sums[] = {s.mass, s.momentum[0], s.momentum[1], s.momentum[2], s.angular_momentum[0], s.angular_momentum[1],
                     s.angular_momentum[2], s.kinetic, s.potential, double(s.particles), interior, held, area};
    S.comm->sum(sums, int(std::size(sums)));
    s.mass = sums[0];
    s.momentum = {sums[1], sums[2], sums[3]};
    s.angular_momentum = {sums[4], sums[5], sums[6]};
    s.kinetic = sums[7], s.potential = sums[8];
    s.particles = std::size_t(sums[9]);
    const double cell = std::pow(double(grid_.dx), Dim);
    s.volume = double(s.particles) * (sums[10] > 0 ? cell * sums[10] / sums[11] : double(particle_volume_));
    s.surface = double(sigma_) * sums[12];
    s.cfl = double(cfl_reached_);  // global already (max_speed_ is)
    cfl_reached_ = 0;
    return s;
  }
  // Liquid volume: the particles times the volume each one fills in the bulk, dx^Dim over the mean
  // count of the interior cells (a cell whose 3^Dim block of cells all hold particles). Liquid
  // that bunches up raises that count and shows as lost volume; liquid that spreads lowers it.
  // Counting every cell that holds a particle as full would not do: a splash of one or two
  // particles per cell would count as whole cells of liquid (+13% in the 3D dam break while its
  // bulk was 2% denser than at rest). With no interior cell (a spray, a thin sheet) each particle
  // counts its seeding volume.
  std::vector<std::uint16_t> count(std::size_t(grid_.num_cells()), 0);
  for (const auto& x : particles_.x) {
    typename Grid::IVec c;
    for (int d = 0; d < Dim; ++d)
      c[d] = std::clamp(int(std::floor((x[d] - grid_.origin[d]) / grid_.dx)), 0, grid_.res[d] - 1);
    auto& n = count[std::size_t(grid_.cell(c))];
    n += n < std::numeric_limits<std::uint16_t>::max();
  }
  std::int64_t interior = 0, held = 0;
  for (std::int64_t k = 0; k < std::int64_t(count.size()); ++k) {
    if (count[std::size_t(k)] == 0) continue;
    const typename Grid::IVec c = grid_.cell_coord(k);
    bool inside = true;
    for (int d = 0; d < Dim; ++d) inside = inside && c[d] > 0 && c[d] + 1 < grid_.res[d];
    for (int o = 0; inside && o < (Dim == 3 ? 27 : 9); ++o) {
      typename Grid::IVec q = c;
      for (int d = 0, m = o; d < Dim; ++d, m /= 3) q[d] += m % 3 - 1;
      inside = count[std::size_t(grid_.cell(q))] > 0;
    }
    if (inside) ++interior, held += count[std::size_t(k)];
  }
  const double cell = std::pow(double(grid_.dx), Dim);
  s.volume = double(particles_.size()) * (interior > 0 ? cell * double(interior) / double(held) : double(particle_volume_));
  if (sigma_ > T(0)) s.surface = double(sigma_) * surface_area({});
  s.cfl = double(cfl_reached_);
  cfl_reached_ = 0;
  return s;
}

template <class T, int Dim>
T FlipSolver<T, Dim>::fluid_cell_volume() const {
  std::int64_t n = 0;
  for (auto l : grid_.label) n += l == Grid::Fluid;
  return T(n) * std::pow(grid_.dx, T(Dim));
}

template <class T, int Dim>
Frame FlipSolver<T, Dim>::frame(const std::vector<std::string>& attributes) const {
  Frame data = frame_view(attributes);
  data.own();
  return data;
}

namespace detail {
/// The frame of particles P (columns borrowed from P).
template <class T, int Dim>
Frame particle_frame(const FlipParticles<T, Dim>& P, double time, const std::string& source,
                     const std::vector<std::string>& attributes) {
  static constexpr std::uint16_t kNoMaterial = 0;  // a scene of one liquid stores no material channel
  slurry::detail::VertexFrame out("flip ", time, source, P.size());
  for (const auto& a : attributes) {
    if (a == "position") {
      out.borrow_positions<Dim>(P.x);
    } else if (a == "velocity") {
      out.borrow_velocities<Dim>(P.v);
    } else if (a == "material") {
      if (P.has_material)
        out.borrow_column("material", P.material);
      else
        out.borrow_constant("material", kNoMaterial);
    } else if (a == "id") {
      out.borrow_column("id", P.id);
    }
  }
  return std::move(out.data());
}

/// P's particles in ascending id.
template <class T, int Dim>
void sort_by_id(FlipParticles<T, Dim>& P) {
  std::vector<std::uint32_t> order(P.size());
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(), [&P](std::uint32_t a, std::uint32_t b) { return P.id[a] < P.id[b]; });
  typename FlipParticles<T, Dim>::PermuteBuffers spare;
  P.permute(order, spare);
}
}  // namespace detail

template <class T, int Dim>
Frame FlipSolver<T, Dim>::frame_view(const std::vector<std::string>& attributes) const {
  if (!split_) return detail::particle_frame(particles_, time_, scene_.source, attributes);
  // Gathered on rank 0 in ascending id (whatever the process count), which writes the frame;
  // kept there for particle_storage().
  auto& S = *split_;
  S.gathered = gather_particles();
  if (S.comm->rank() != 0) return {};
  return detail::particle_frame(S.gathered, time_, scene_.source, attributes);
}

template <class T, int Dim>
FlipParticles<T, Dim> FlipSolver<T, Dim>::gather_particles() const {
  std::string mine;
  for (std::size_t p = 0; p < particles_.size(); ++p) detail::pack_particle(particles_, p, mine);
  const auto parts = split_->comm->gather(mine);
  FlipParticles<T, Dim> G;
  G.affine = particles_.affine;
  G.has_material = particles_.has_material;
  for (const auto& part : parts) detail::unpack_particles(part, G);
  detail::sort_by_id(G);
  G.next_id = particles_.next_id;  // the same on every rank: ids are only given at seeding
  return G;
}

template <class T, int Dim>
Frame FlipSolver<T, Dim>::own_frame(const std::vector<std::string>& attributes) const {
  if (!split_) return frame(attributes);
  FlipParticles<T, Dim> P = particles_;
  detail::sort_by_id(P);
  const bool requested = std::find(attributes.begin(), attributes.end(), "id") != attributes.end();
  std::vector<std::string> columns = attributes;
  if (!requested) columns.push_back("id");
  Frame part = detail::particle_frame(P, time_, scene_.source, columns);
  part.own();
  part.comments.push_back("slurry part " + std::to_string(split_->comm->rank()) + " of " +
                          std::to_string(split_->comm->size()) + (requested ? " id=requested" : " id=added"));
  return part;
}

template <class T, int Dim>
Frame FlipSolver<T, Dim>::whitewater_frame_view() const {
  if (!whitewater_) return {};
  if (split_) {  // every rank's, gathered on rank 0 in id order (which writes it)
    split_->whitewater_gathered = gather_whitewater();
    if (split_->comm->rank() != 0) return {};
  }
  const auto& W = split_ ? split_->whitewater_gathered : whitewater_->particles();
  slurry::detail::VertexFrame out("flip whitewater ", time_, scene_.source, W.size());
  out.borrow_positions<Dim>(W.x);
  out.borrow_velocities<Dim>(W.v);
  out.borrow_column("type", W.type);
  out.borrow_column("id", W.id);
  return std::move(out.data());
}

template <class T, int Dim>
ParticleStorage FlipSolver<T, Dim>::particle_storage() const {
  // A split run's rank 0 shows every particle as of the last frame; other ranks their own.
  const auto& P = split_ && split_->comm->rank() == 0 ? split_->gathered : particles_;
  ParticleStorage s;
  s.precision = std::is_same_v<T, double> ? Precision::Double : Precision::Float;
  s.dimension = Dim;
  s.count = P.size();
  s.x = P.x.data();
  s.v = P.v.data();
  s.id = P.id.data();
  if (P.has_material) s.material = P.material.data();
  return s;
}

}  // namespace slurry::flip

#include "flip/split_phases.h"
