// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// The transfer phases of the substep: the periodic re-sort into bin order, P2G (scatter per
// bin into block-coloured patches), the grid update with boundaries and colliders, G2P, the
// plastic return mapping, and the liquids' wave speeds at their most compressed particle.
#pragma once

namespace slurry {

template <class T, int Dim>
void MpmSolver<T, Dim>::reorder_particles() {
  // Particles are stored in bin order, so that the transfers stream through memory. Each channel
  // is permuted in place by following the cycles of the order (new[j] = old[order[j]]): one
  // value of temporary storage and one bit per particle, where a gather through a scratch
  // channel would hold a second copy of the largest channel (36 bytes per particle in 3D float).
  // The particles moved in a few substeps, so the cycles are short and local. Each walk is
  // serial, bound by memory latency; the channels are shared out between the threads, each
  // with a bitmap of its own (the parallel gather of one channel was slower on two threads than
  // on one, benchmarks/RESULTS.md, "3D MPM throughput"). Channel k goes to task k mod tasks, one task per thread: in
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
  for (const auto n : projected_scratch_) projected_ += n;
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
      if (split_) prepare_halo<Order>();
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
          if (split_) keep_halo_patch<Order>(g, patch);
        });
      }
      if (split_) exchange_halo<Order>(grid);
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
    if (mat.plastic_kind == PlasticModel::None || project_in_p2g_[bin.material]) return;
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
    if (!fluid_[bin.material]) return;
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

}  // namespace slurry
