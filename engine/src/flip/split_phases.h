// FlipSolver's phases of a run split over processes (split.h); included by flip_solver_impl.h.
#pragma once
#include <algorithm>
#include <cstring>
#include <limits>
#include <numeric>
#include <string>
#include <vector>

#include "flip/split.h"
#include "mpm/domain_split.h"
#include "slurry/engine/flip/flip_solver.h"

namespace slurry::flip {

template <class T, int Dim>
void FlipSolver<T, Dim>::split_particles() {
  auto& S = *split_;
  const int ranks = S.comm->size();
  S.per_axis = slurry::detail::process_grid<Dim>(ranks, S.blocks());
  if (S.per_axis.empty()) {
    std::string lattice;
    for (int d = 0; d < Dim; ++d) lattice += (d ? " x " : "") + std::to_string(S.blocks()[d]);
    throw SceneError(scene_.source + ": domain: split over " + std::to_string(ranks) + " processes, but the grid's " +
                     lattice + " blocks of " + std::to_string(S.kBlock) + " cells along each axis give no box of at "
                     "least one block to each; expected a process count that factors into at most that many along each "
                     "axis (mpirun -np)");
  }
  // The window's band: the extrapolation fills `layers` layers of faces and its linear rule
  // reads two faces behind each, so a face's extrapolated value depends on faces up to
  // 2 x layers cells away (fill_air_velocities()); 2 more for the kernel's reach. Ghost
  // particles: the level set of an air cell next to the box's ring reads the particles of its
  // 3^Dim neighbours (level_set.h), 2 cells from the box, which also covers the transfer's
  // reach (a particle's kernel touches faces up to order_ cells away); one more with the
  // quadratic kernel. With 1 the dam break tests of tests/mpi fail; with 2, 3 and 4 their frames
  // are the same.
  const double reach = scene_.solver.advection == AdvectionScheme::Midpoint ? 0.5 : 1.0;
  const int layers = std::max(int(std::ceil(reach * scene_.solver.cfl)) + order_ + 1, order_ + Dim - 1);
  S.band = 2 * layers + 2;
  if (whitewater_) S.band = std::max(S.band, detail::whitewater_ring(scene_.solver.whitewater.bubble_depth));
  S.reach = layers;
  S.ghost = order_ + 1;
  // The subcell surface (solver.free_surface): a fluid cell of the ring takes phi from the air
  // cells of its 3^Dim neighbourhood, whose level sets read particles 3 cells from the box, and
  // its sliver rule reads the labels of its fluid neighbours' neighbours, 3 cells out (pressure.h).
  if (subcell_surface_) S.ghost = std::max(S.ghost, 3);
  // Surface tension: the curvature of a cell next to the box reads the colour function up to 6
  // cells away, which is kept only within 5 cells of the labelled surface (surface_tension.h),
  // so the labels must be exact up to 11 cells out: every particle of the window comes as a ghost.
  if (sigma_ > T(0)) S.ghost = S.band;
  S.place(S.block_counts(particles_.x), false);  // every rank holds every particle here
  S.total = particles_.size();
  const int me = S.comm->rank();
  std::size_t n = 0;
  for (std::size_t p = 0; p < particles_.size(); ++p)
    if (S.owner(particles_.x[p]) == me) particles_.move(n++, p);
  particles_.truncate(n);
  S.own = n;
  fit_window();
}

template <class T, int Dim>
void FlipSolver<T, Dim>::fit_window() {
  const auto& S = *split_;
  grid_.resize(IVec(S.whi - S.wlo), S.dx, S.origin, !solids_.empty());
  grid_.offset = S.wlo;
}

template <class T, int Dim>
void FlipSolver<T, Dim>::rebalance() {
  // New boxes from this frame's particles; the grid follows its window (the pressure, the next
  // solve's start, kept where the windows overlap); particles go to their new owners, which
  // need not be peers: every rank exchanges with every other.
  auto& S = *split_;
  const IVec old_lo = S.wlo, old_hi = S.whi;
  S.place(S.block_counts(particles_.x), true);
  if (S.wlo != old_lo || S.whi != old_hi) {
    const IVec old_res = old_hi - old_lo;
    std::vector<T> old_pressure;
    old_pressure.swap(grid_.pressure);
    fit_window();
    for (std::int64_t k = 0; k < grid_.num_cells(); ++k) {
      const IVec i = S.domain_cell(k);
      if ((i.array() >= old_lo.array()).all() && (i.array() < old_hi.array()).all())
        grid_.pressure[std::size_t(k)] = old_pressure[std::size_t(transfer::lattice_index<Dim>(IVec(i - old_lo), old_res))];
    }
    faces_ready_ = false;
  }
  std::vector<int> everyone;
  for (int q = 0; q < S.comm->size(); ++q)
    if (q != S.comm->rank()) everyone.push_back(q);
  send_to_owners(everyone);
  if (whitewater_) send_whitewater_to_owners(true);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::exchange_ghosts() {
  auto& S = *split_;
  auto& P = particles_;
  std::vector<std::string> out(S.peers.size());
  const IVec inner_lo = S.lo.array() + S.ghost, inner_hi = S.hi.array() - S.ghost;
  for (std::size_t p = 0; p < P.size(); ++p) {
    const IVec c = S.cell_of(P.x[p]);
    if ((c.array() >= inner_lo.array()).all() && (c.array() < inner_hi.array()).all()) continue;  // deep inside
    for (std::size_t k = 0; k < S.peers.size(); ++k)
      if (((c.array() >= S.peer_lo[k].array() - S.ghost) && (c.array() < S.peer_hi[k].array() + S.ghost)).all())
        detail::pack_particle(P, p, out[k]);
  }
  const auto in = S.comm->exchange(S.peers, out);
  S.own = P.size();
  for (const auto& m : in) detail::unpack_particles(m, P);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::drop_ghosts() {
  // Sorted, the particles from before the ghosts are those whose sorted slot came from below own.
  auto& S = *split_;
  std::size_t n = 0;
  for (std::size_t i = 0; i < particles_.size(); ++i)
    if (sort_.order[i] < S.own) particles_.move(n++, i);
  particles_.truncate(n);
  S.own = n;
}

template <class T, int Dim>
void FlipSolver<T, Dim>::migrate() {
  send_to_owners(split_->peers);  // a particle moves less than a band per substep
}

template <class T, int Dim>
void FlipSolver<T, Dim>::send_to_owners(const std::vector<int>& ranks) {
  // Keeps the particles this rank owns and sends each other one to its owner, which must be one
  // of `ranks` (distinct, mutual between the ranks, as Communicator::exchange needs).
  auto& S = *split_;
  auto& P = particles_;
  const int me = S.comm->rank();
  std::vector<int> slot(std::size_t(S.comm->size()), -1);
  for (std::size_t k = 0; k < ranks.size(); ++k) slot[std::size_t(ranks[k])] = int(k);
  std::vector<std::string> out(ranks.size());
  const std::size_t n = detail::keep_own_pack_others(
      P.size(), me, slot, out,
      [&](std::size_t p) {
        const int q = S.owner(P.x[p]);
        if (q != me && slot[std::size_t(q)] < 0)
          throw SimulationError(scene_.source + ": a particle moved beyond the ranks next to rank " +
                                std::to_string(me) + " in one substep (more than " + std::to_string(S.band) +
                                " cells); expected a smaller solver.cfl");
        return q;
      },
      [&](std::size_t kept, std::size_t p) { P.move(kept, p); },
      [&](std::size_t p, std::string& message) { detail::pack_particle(P, p, message); });
  P.truncate(n);
  const auto in = S.comm->exchange(ranks, out);
  for (const auto& m : in) detail::unpack_particles(m, P);
  S.own = P.size();
}

template <class T, int Dim>
template <class Target>
ProjectionReport FlipSolver<T, Dim>::split_projection(T dt, const Target& target_flux) {
  auto& S = *split_;
  auto& g = grid_;
  // The solve is PETSc's: the one-process preconditioner (a multigrid hierarchy) is not built.
  ProjectionOptions opt = projection_options_;
  opt.preconditioner = Preconditioner::None;
  pressure_.prepare(g, dt, opt, target_flux);
  // Rows: this rank's unknowns in its box's cell order, after every row of the ranks before it.
  const std::int64_t cells = g.num_cells();
  std::vector<std::int64_t> row(std::size_t(cells), -1);
  std::vector<std::int64_t> mine;
  S.for_region(-1, S.lo, S.hi, [&](std::int64_t c) {
    if (pressure_.is_unknown(c)) row[std::size_t(c)] = std::int64_t(mine.size()), mine.push_back(c);
  });
  const std::int64_t count = std::int64_t(mine.size());
  const auto counts = S.comm->all_gather(std::string(reinterpret_cast<const char*>(&count), sizeof count));
  std::int64_t first = 0, rows = 0;
  for (int r = 0; r < int(counts.size()); ++r) {
    std::int64_t n = 0;
    std::memcpy(&n, counts[std::size_t(r)].data(), sizeof n);
    if (r < S.comm->rank()) first += n;
    rows += n;
  }
  for (const auto c : mine) row[std::size_t(c)] += first;
  S.exchange(row, -1, 1);  // the ring's row numbers
  DistributedSystem A;
  A.first = first;
  std::vector<double> x;
  double air = 0;
  for (const auto c : mine) {
    const IVec i = g.cell_coord(c);
    A.columns.push_back(row[std::size_t(c)]);
    A.values.push_back(pressure_.diagonal(c));
    for (int d = 0; d < Dim; ++d)
      for (int side = 0; side < 2; ++side) {
        const int nd = i[d] + (side ? 1 : -1);
        if (nd < 0 || nd >= g.res[d]) continue;
        const std::int64_t nb = side ? c + g.cell_stride(d) : c - g.cell_stride(d);
        if (row[std::size_t(nb)] < 0 || g.label[std::size_t(nb)] != Grid::Fluid) continue;
        const std::int64_t f = g.face(d, i) + (side ? g.face_stride(d, d) : 0);
        const T w = g.open_weight(d, i[d] + side, f, side ? nb : c);
        if (w <= T(0)) continue;
        A.columns.push_back(row[std::size_t(nb)]);
        A.values.push_back(-double(w));
      }
    A.row_start.push_back(std::int64_t(A.columns.size()));
    A.rhs.push_back(pressure_.rhs(c));
    x.push_back(pressure_.value(c));
    air += pressure_.touches_air(c) ? 1 : 0;
  }
  S.comm->sum(&air, 1);
  // A liquid with no free surface anywhere (a closed tank) determines its pressure up to a constant.
  A.constant_null_space = air == 0;
  ProjectionReport rep;
  rep.unknowns = rows;
  rep.converged = true;
  if (rows > 0) {
    const DistributedSolve r = S.comm->solve_spd(A, x, opt.tolerance, opt.max_iterations);
    rep.iterations = r.iterations;
    rep.relative_residual = r.residual;
    rep.converged = r.converged;
  }
  // The solution on this rank's unknowns, then the ring's from their owners; the other unknowns
  // of the window (beyond the ring) take 0: their faces are replaced by their owners' afterwards.
  std::vector<double> value(std::size_t(cells), 0.0);
  for (std::size_t k = 0; k < mine.size(); ++k) value[std::size_t(mine[k])] = x[k];
  S.exchange(value, -1, 1);
  for (std::int64_t c = 0; c < cells; ++c)
    if (pressure_.is_unknown(c)) pressure_.value(c) = value[std::size_t(c)];
  pressure_.finish(g, dt, opt, target_flux, rep, [&S](std::int64_t c) { return S.in_box(S.domain_cell(c)); });
  S.comm->max(&rep.max_divergence, 1);
  return rep;
}

template <class T, int Dim>
std::vector<double> FlipSolver<T, Dim>::own_cell_counts(int depth) const {
  // Particles per window cell (this rank's own), then the counts of `depth` cells around the box
  // from their owners.
  auto& S = *split_;
  std::vector<std::uint32_t> count(std::size_t(grid_.num_cells()), 0);
  for (const auto& x : particles_.x) ++count[std::size_t(S.local_cell(S.cell_of(x)))];
  S.exchange(count, -1, depth);
  return std::vector<double>(count.begin(), count.end());
}

}  // namespace slurry::flip
