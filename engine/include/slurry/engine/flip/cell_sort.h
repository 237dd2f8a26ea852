#pragma once
/// \file cell_sort.h
/// Counting sort of particles by the grid cell that contains them (row-major cell order, stable
/// in particle index), so that the particles of a cell -- and of a whole column of cells along
/// the last axis -- are one contiguous index range. P2G scatters from these ranges in slabs of
/// cells along x (face_transfer.h) and the cell labelling reads them per row: race-free without
/// atomics and independent of the thread count.
/// Buffers are kept between calls (no allocation once the particle count has settled).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

#include "slurry/transfer/parallel.h"

namespace slurry::flip {

template <class T, int Dim>
struct CellSort {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;

  std::vector<std::uint32_t> key;    ///< cell of each particle (input order)
  std::vector<std::uint32_t> start;  ///< particles of cell k are [start[k], start[k+1]) after sorting
  std::vector<std::uint32_t> order;  ///< sorted position i holds input particle order[i]

  /// Cell containing x (clamped to the grid).
  /// `offset`: the grid's first cell in a larger grid of the same origin (MacGrid::offset).
  static std::int64_t cell_of(const Vec& x, const Vec& origin, T inv_dx, const IVec& res, const IVec& offset = IVec::Zero()) {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) {
      int i = int(std::floor((x[d] - origin[d]) * inv_dx)) - offset[d];
      i = std::clamp(i, 0, res[d] - 1);
      k = k * res[d] + i;
    }
    return k;
  }

  /// Computes key, the per-cell histogram `start` (prefix sums) and, if `permute`, the stable
  /// sorting permutation `order`. `offset` as in cell_of().
  void build(const std::vector<Vec>& x, const Vec& origin, T dx, const IVec& res, bool permute = true,
             const IVec& offset = IVec::Zero()) {
    const std::int64_t n = std::int64_t(x.size());
    std::int64_t cells = 1;
    for (int d = 0; d < Dim; ++d) cells *= res[d];
    // 32-bit cell and particle indices and cell ranges (a dense FLIP grid of 2^32 cells would
    // need a terabyte).
    if (cells > std::int64_t(std::numeric_limits<std::uint32_t>::max()) ||
        n > std::int64_t(std::numeric_limits<std::uint32_t>::max()))
      throw std::length_error("FLIP cell sort: more than 2^32 - 1 cells or particles");
    key.resize(std::size_t(n));
    const T inv_dx = T(1) / dx;
    parallel::parallel_for(0, n, [&](std::int64_t p) { key[p] = std::uint32_t(cell_of(x[p], origin, inv_dx, res, offset)); });
    start.assign(std::size_t(cells + 1), 0);
    for (std::int64_t p = 0; p < n; ++p) ++start[std::size_t(key[p] + 1)];
    for (std::int64_t k = 0; k < cells; ++k) start[k + 1] += start[k];
    if (!permute) return;
    order.resize(std::size_t(n));
    // Stable scatter: particles keep their relative order within a cell. start[k] serves as
    // cell k's cursor and ends at the old start[k + 1]; shifting it back restores the ranges
    // (no per-cell cursor array: 8 bytes a cell less).
    for (std::int64_t p = 0; p < n; ++p) order[std::size_t(start[key[p]]++)] = std::uint32_t(p);
    for (std::int64_t k = cells; k > 0; --k) start[k] = start[k - 1];
    start[0] = 0;
  }

  /// Particles in cell k.
  std::int64_t count(std::int64_t k) const { return std::int64_t(start[k + 1]) - std::int64_t(start[k]); }

};

}  // namespace slurry::flip
