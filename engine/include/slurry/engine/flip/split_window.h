#pragma once
/// \file split_window.h
/// Where one process's grid lies in the domain's when a FLIP run is split over processes, for the
/// seeders of new particles (reseeding, seeding.h; whitewater, whitewater.h): a process seeds only
/// in the cells it owns, its hashes count the domain's cell, and its new particles take the ids
/// one process would give them, so that the processes together draw and number what one process
/// would.
#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "slurry/transfer/lattice.h"

namespace slurry::flip {

template <int Dim>
struct SplitWindow {
  using IVec = Eigen::Matrix<int, Dim, 1>;
  IVec domain_res = IVec::Zero();  ///< the domain's cells per axis
  /// The cells this process owns, [lo, hi) in the grid's coordinates.
  IVec lo = IVec::Zero(), hi = IVec::Zero();
  /// Takes this process's new particles per cell (domain cell index, count; in ascending cell
  /// order), replaces each count by the cell's first id over every process's cells in the domain's
  /// order, and returns the next id after them all. It may talk to the other processes: every
  /// process calls the seeder alike.
  std::function<std::uint32_t(std::vector<std::pair<std::uint64_t, std::uint32_t>>&)> number;

  /// Whether the grid's cell i is this process's own.
  bool owns(const IVec& i) const {
    return (i.array() >= lo.array()).all() && (i.array() < hi.array()).all();
  }
};

/// The cell counter of a seeder's hash for the grid's cell c: the domain's cell index (the
/// grid's cells are the domain's from g.offset on), the grid's own index in one process (w null).
template <class Grid, int Dim>
std::uint64_t domain_cell(const Grid& g, std::int64_t c, const SplitWindow<Dim>* w) {
  if (!w) return std::uint64_t(c);
  const Eigen::Matrix<int, Dim, 1> i = g.cell_coord(c) + g.offset;
  return std::uint64_t(transfer::lattice_index<Dim>(i, w->domain_res));
}

/// The first id of each of the grid's cells c with new particles (count(c) > 0) over every
/// process's cells, through w.number, in first_id[c] (resized to the grid's cells; the others
/// untouched); returns the next id after them all.
template <class Grid, int Dim, class Count>
std::uint32_t number_new_particles(const Grid& g, const SplitWindow<Dim>& w, Count&& count,
                                   std::vector<std::uint32_t>& first_id) {
  const std::int64_t cells = g.num_cells();
  std::vector<std::pair<std::uint64_t, std::uint32_t>> mine;
  std::vector<std::int64_t> at;
  for (std::int64_t c = 0; c < cells; ++c)
    if (const std::uint32_t n = count(c); n > 0)
      mine.emplace_back(domain_cell(g, c, &w), n), at.push_back(c);
  const std::uint32_t next_id = w.number(mine);
  first_id.resize(std::size_t(cells));
  for (std::size_t k = 0; k < at.size(); ++k) first_id[std::size_t(at[k])] = mine[k].second;
  return next_id;
}

}  // namespace slurry::flip
