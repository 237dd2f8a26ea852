// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// The domain split over MPI ranks (mpm_solver.h, "Runs split over processes"): slab borders from
// particle counts, migrating particles to the rank that owns their slab, ghost particles within
// a kernel's reach of a border, gathering every particle for frames and checkpoints.
#pragma once

namespace slurry {

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

}  // namespace slurry
