#pragma once
/// \file lattice.h
/// Row-major lattice indexing (the last axis fastest), shared by the particle bins' block keys
/// (blocks.h) and the FLIP MAC grid's cells and faces (engine/flip/mac_grid.h).
#include <Eigen/Core>
#include <cstdint>

namespace slurry::transfer {

/// The row-major index of coordinates i in a lattice of res[d] points per axis.
template <int Dim, class Coord, class Res>
std::int64_t lattice_index(const Coord& i, const Res& res) {
  std::int64_t k = i[0];
  for (int d = 1; d < Dim; ++d) k = k * res[d] + i[d];
  return k;
}

/// The coordinates of row-major index k in a lattice of res[d] points per axis.
template <int Dim, class Res>
Eigen::Matrix<int, Dim, 1> lattice_coord(std::int64_t k, const Res& res) {
  Eigen::Matrix<int, Dim, 1> i;
  for (int d = Dim - 1; d >= 0; --d) {
    i[d] = int(k % res[d]);
    k /= res[d];
  }
  return i;
}

}  // namespace slurry::transfer
