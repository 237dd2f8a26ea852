// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// The substep and its opening phases: step() runs the phases in order (binning, the periodic
// re-sort, P2G with the stress update, the grid update, G2P, the return mapping, sleeping);
// the stress of a material range, the implicit grid update, binning particles into grid blocks.
#pragma once

namespace slurry {

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
  bin_particles();
  lap(phase_times_.binning);
  if (implicit_ || steps_ % kReorderInterval == 0) reorder_particles();
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
typename MpmSolver<T, Dim>::IVec MpmSolver<T, Dim>::block_order(const Vec& x) const {
  // The expression of bin_particles_order, so that a particle's block is its bin's.
  const T inv_dx = T(1) / dx_;
  IVec b;
  for (int d = 0; d < Dim; ++d)
    b[d] = std::clamp(transfer::BSpline<Order>::base((x[d] - origin_[d]) * inv_dx) >> transfer::BlockShape<Dim>::log2, 0,
                      split_->boxes.res[d] - 1);
  return b;
}

template <class T, int Dim>
typename MpmSolver<T, Dim>::IVec MpmSolver<T, Dim>::block_of(const Vec& x) const {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: return block_order<1>(x);
    case KernelKind::Quadratic: return block_order<2>(x);
    case KernelKind::Cubic: break;
  }
  return block_order<3>(x);
}

}  // namespace slurry
