// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// Sleeping material (solver.sleep): blocks whose particles have been still for a while stop
// being transferred and wake when a moving neighbour reaches them.
#pragma once

namespace slurry {

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

}  // namespace slurry
