#pragma once
// Where each cell's particles start in a list of particles sorted by cell key (the keys numbering
// a box of cells), as a dense table over every cell of the box: a run of consecutive cells is
// then two reads. Shared by the anisotropic field's neighbourhoods and the velocity sampler.
#include <algorithm>
#include <cstdint>

#include "slurry/transfer/parallel.h"
#include "vdb/buffer.h"

namespace slurry::io::detail {

/// Whether a table over `cells` cells is worth it for `n` particles: at most 4 cells per particle
/// (or 2^20 cells), else the callers search the sorted keys instead.
inline bool dense_cell_table(double cells, std::size_t n) {
  return cells <= std::max(4.0 * double(n), double(1 << 20));
}

/// first[k] (k in [0, cells]) = the number of particles in cells before k, for `keys` sorted in
/// ascending order, each below `cells`: the sorted particle i that starts a run of keys is the
/// first of its cell and of the empty cells just before it.
inline UninitVector<std::uint32_t> cell_starts(const UninitVector<std::uint64_t>& keys, std::size_t cells) {
  const std::size_t n = keys.size();
  UninitVector<std::uint32_t> first(cells + 1);
  slurry::parallel::parallel_for(0, std::int64_t(n) + 1, [&](std::int64_t i) {
    const std::size_t from = i == 0 ? 0 : std::size_t(keys[std::size_t(i) - 1]) + 1;
    const std::size_t to = std::size_t(i) == n ? cells : std::size_t(keys[std::size_t(i)]);
    for (std::size_t k = from; k <= to; ++k) first[k] = std::uint32_t(i);
  });
  return first;
}

}  // namespace slurry::io::detail
