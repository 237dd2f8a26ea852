// FlipSolver's whitewater in a run split over processes (split.h). Each process keeps the
// secondary particles in its box and runs whitewater.h's phases on its window:
//   1. the labels and level set of the ring around its box come from their owners
//      (whitewater_ring() cells), so that the depth field is exact over the box and the cells
//      next to it;
//   2. depth and classification at t, the motion over dt; particles that left the box go to the
//      owner of their new cell (to every rank if one flew past the peers: spray is not bound by
//      the liquid's CFL number);
//   3. classification and removal where they ended; generation in the cells it owns, the hash
//      counting the domain's cell and the ids numbered over every process's cells in the
//      domain's order, as one process draws and numbers them; new particles that start beyond
//      the box go to their owners;
//   4. the limit over every process: the oldest (smallest ids) of all removed first.
// Compiled apart from the solver's phases (flip_solver_impl.h), as state.cpp is.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "flip/split.h"
#include "slurry/engine/flip/flip_solver.h"

namespace slurry::flip {

template <class T, int Dim>
void FlipSolver<T, Dim>::split_whitewater(T dt) {
  auto& S = *split_;
  auto& W = *whitewater_;
  const int ring = std::min(S.band, detail::whitewater_ring(scene_.solver.whitewater.bubble_depth));
  S.exchange(grid_.label, -1, ring);
  S.exchange(grid_.phi, -1, ring);
  W.begin(grid_, x_lo_, x_hi_);
  W.move_particles(grid_, dt);
  send_whitewater_to_owners(false);
  W.classify_and_remove(grid_, solids_, time_ + double(dt));
  typename Whitewater<T, Dim>::Window window;
  window.domain_res = S.res;
  window.lo = S.lo - S.wlo;
  window.hi = S.hi - S.wlo;
  window.number = [&S, &W](std::vector<std::pair<std::uint64_t, std::uint32_t>>& mine) {
    return S.number_new(mine, W.particles().next_id);
  };
  W.generate_in(grid_, dt, steps_, window);
  send_whitewater_to_owners(false);
  limit_split_whitewater();
}

template <class T, int Dim>
void FlipSolver<T, Dim>::send_whitewater_to_owners(bool everyone) {
  auto& S = *split_;
  auto& W = whitewater_->particles();
  const int me = S.comm->rank(), ranks = S.comm->size();
  std::vector<int> slot(std::size_t(ranks), -1);
  for (std::size_t k = 0; k < S.peers.size(); ++k) slot[std::size_t(S.peers[k])] = int(k);
  // A particle whose position is not finite stays (remove() drops it).
  const auto owner = [&](std::size_t i) { return std::isfinite(double(W.x[i].sum())) ? S.owner(W.x[i]) : me; };
  double far = everyone ? 1 : 0;
  for (std::size_t i = 0; i < W.size() && far == 0; ++i)
    if (const int q = owner(i); q != me && slot[std::size_t(q)] < 0) far = 1;
  S.comm->max(&far, 1);
  std::vector<int> to = S.peers;
  if (far > 0) {
    to.clear();
    for (int q = 0; q < ranks; ++q)
      if (q != me) to.push_back(q);
    std::fill(slot.begin(), slot.end(), -1);
    for (std::size_t k = 0; k < to.size(); ++k) slot[std::size_t(to[k])] = int(k);
  }
  std::vector<std::string> out(to.size());
  const std::size_t n = detail::keep_own_pack_others(
      W.size(), me, slot, out, owner, [&](std::size_t kept, std::size_t i) { W.move(kept, i); },
      [&](std::size_t i, std::string& message) { detail::pack_whitewater(W, i, message); });
  W.resize(n);
  for (const auto& m : S.comm->exchange(to, out)) detail::unpack_whitewater(m, W);
  detail::sort_whitewater(W);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::limit_split_whitewater() {
  // At most max_particles over every rank: the `drop` smallest ids go. Ids are distinct, so the
  // smallest theta with count(id < theta) >= drop over the ranks (bisection on sums) has exactly
  // `drop` below it.
  auto& S = *split_;
  auto& W = whitewater_->particles();
  double total = double(W.size());
  S.comm->sum(&total, 1);
  const double cap = double(scene_.solver.whitewater.max_particles);
  if (total <= cap) return;
  const double drop = total - cap;
  const auto below = [&W](std::uint64_t theta) {
    return std::size_t(std::lower_bound(W.id.begin(), W.id.end(), theta,
                                        [](std::uint32_t id, std::uint64_t t) { return std::uint64_t(id) < t; }) -
                       W.id.begin());
  };
  std::uint64_t lo = 0, hi = std::uint64_t(1) << 32;  // count(id < lo) < drop <= count(id < hi)
  while (hi - lo > 1) {
    const std::uint64_t mid = lo + (hi - lo) / 2;
    double c = double(below(mid));
    S.comm->sum(&c, 1);
    (c >= drop ? hi : lo) = mid;
  }
  const std::size_t n = below(hi);
  for (std::size_t i = n; i < W.size(); ++i) W.move(i - n, i);
  W.resize(W.size() - n);
  whitewater_->removed() += std::int64_t(n);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::count_split_whitewater() {
  const WhitewaterCounts c = whitewater_->counts();
  double v[5] = {double(c.spray), double(c.foam), double(c.bubble), double(c.generated), double(c.removed)};
  split_->comm->sum(v, 5);
  auto& all = split_->whitewater;
  all.spray = std::size_t(v[0]), all.foam = std::size_t(v[1]), all.bubble = std::size_t(v[2]);
  all.generated = std::int64_t(v[3]), all.removed = std::int64_t(v[4]);
}

template <class T, int Dim>
WhitewaterCounts FlipSolver<T, Dim>::whitewater_counts() const {
  if (!whitewater_) return {};
  return split_ ? split_->whitewater : whitewater_->counts();
}

template <class T, int Dim>
WhitewaterParticles<T, Dim> FlipSolver<T, Dim>::gather_whitewater() const {
  const auto& W = whitewater_->particles();
  std::string mine;
  for (std::size_t i = 0; i < W.size(); ++i) detail::pack_whitewater(W, i, mine);
  WhitewaterParticles<T, Dim> all;
  all.next_id = W.next_id;
  for (const auto& m : split_->comm->gather(mine)) detail::unpack_whitewater(m, all);
  detail::sort_whitewater(all);
  return all;
}

#define SLURRY_FLIP_SPLIT_WHITEWATER(T, Dim)                                       \
  template void FlipSolver<T, Dim>::split_whitewater(T);                           \
  template void FlipSolver<T, Dim>::send_whitewater_to_owners(bool);               \
  template void FlipSolver<T, Dim>::limit_split_whitewater();                      \
  template void FlipSolver<T, Dim>::count_split_whitewater();                      \
  template WhitewaterCounts FlipSolver<T, Dim>::whitewater_counts() const;         \
  template WhitewaterParticles<T, Dim> FlipSolver<T, Dim>::gather_whitewater() const;
SLURRY_FLIP_SPLIT_WHITEWATER(float, 2)
SLURRY_FLIP_SPLIT_WHITEWATER(float, 3)
SLURRY_FLIP_SPLIT_WHITEWATER(double, 2)
SLURRY_FLIP_SPLIT_WHITEWATER(double, 3)
#undef SLURRY_FLIP_SPLIT_WHITEWATER

}  // namespace slurry::flip
