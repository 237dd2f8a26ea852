#pragma once
// Particles sorted by cell key (the keys numbering a box of cells) by a counting sort, with where
// each cell's particles start as a dense table over every cell of the box: a run of consecutive
// cells is then two reads. Shared by the anisotropic field's neighbourhoods and blocks, the
// velocity sampler and the mesh's band.
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "slurry/transfer/parallel.h"
#include "vdb/buffer.h"
#include "vdb/radix_sort.h"

namespace slurry::io::detail {

/// Whether a table over `cells` cells is worth it for `n` particles: at most 4 cells per particle
/// (or 2^20 cells), else the callers search the sorted keys instead.
inline bool dense_cell_table(double cells, std::size_t n) {
  return cells <= std::max(4.0 * double(n), double(1 << 20));
}

/// Sorts (keys[i], values[i]) by key, ties in their order (what radix_sort_pairs in radix_sort.h
/// does), for keys each below `cells` with dense_cell_table(cells, keys.size()), and returns
/// where each cell starts: first[k] (k in [0, cells]) = the number of keys below k. The input is
/// cut into parts counted in parallel, each in a table of its own; every (cell, part) is given
/// its place in cell order then part order (the cell's first place is where it starts), and the
/// parts are scattered in parallel, each in its own order. A stable sort has one result, so the
/// parts change only the time.
template <class Keys, class Values>
UninitVector<std::uint32_t> counting_sort_pairs(Keys& keys, Values& values, std::size_t cells) {
  const std::size_t n = keys.size();
  // Parts: one per thread, at most 16, and at most 8 table entries per particle in all (32
  // bytes; a table of `cells` is at most 4 per particle).
  std::size_t parts = std::size_t(std::clamp(slurry::parallel::max_threads(), 1, 16));
  parts = std::max<std::size_t>(1, std::min(parts, 8 * n / std::max<std::size_t>(cells, 1)));
  const std::size_t share = (n + parts - 1) / parts;
  const auto part_begin = [&](std::size_t p) { return std::min(n, p * share); };
  UninitVector<std::uint32_t> count(parts * cells);  // part p's cells at p * cells
  slurry::parallel::parallel_tasks(0, std::int64_t(parts), [&](std::int64_t p) {
    std::uint32_t* c = count.data() + std::size_t(p) * cells;
    std::fill(c, c + cells, 0u);
    for (std::size_t i = part_begin(std::size_t(p)); i < part_begin(std::size_t(p) + 1); ++i) ++c[keys[i]];
  });
  // Places: the cells cut into ranges summed in parallel, the ranges' totals added up in order,
  // then each range's places from its start.
  UninitVector<std::uint32_t> first(cells + 1);
  const std::size_t ranges = std::min<std::size_t>(64, std::max<std::size_t>(1, cells / 4096));
  const auto range_begin = [&](std::size_t r) { return cells * r / ranges; };
  std::vector<std::uint32_t> total(ranges + 1, 0);
  slurry::parallel::parallel_tasks(0, std::int64_t(ranges), [&](std::int64_t r) {
    std::uint32_t sum = 0;
    for (std::size_t p = 0; p < parts; ++p) {
      const std::uint32_t* c = count.data() + p * cells;
      for (std::size_t k = range_begin(std::size_t(r)); k < range_begin(std::size_t(r) + 1); ++k) sum += c[k];
    }
    total[std::size_t(r) + 1] = sum;
  });
  for (std::size_t r = 0; r < ranges; ++r) total[r + 1] += total[r];
  slurry::parallel::parallel_tasks(0, std::int64_t(ranges), [&](std::int64_t r) {
    std::uint32_t at = total[std::size_t(r)];
    for (std::size_t k = range_begin(std::size_t(r)); k < range_begin(std::size_t(r) + 1); ++k) {
      first[k] = at;
      for (std::size_t p = 0; p < parts; ++p) at += std::exchange(count[p * cells + k], at);
    }
  });
  first[cells] = std::uint32_t(n);
  Keys keys_out(n);
  Values values_out(n);
  slurry::parallel::parallel_tasks(0, std::int64_t(parts), [&](std::int64_t p) {
    std::uint32_t* c = count.data() + std::size_t(p) * cells;
    for (std::size_t i = part_begin(std::size_t(p)); i < part_begin(std::size_t(p) + 1); ++i) {
      const std::uint32_t at = c[keys[i]]++;
      keys_out[at] = keys[i];
      values_out[at] = values[i];
    }
  });
  keys.swap(keys_out);
  values.swap(values_out);
  return first;
}

/// Sorts (keys[i], values[i]) by key, ties in their order, for keys each below `cells`: by
/// counting_sort_pairs where dense_cell_table allows a table, returning where each cell starts;
/// else by radix_sort_pairs, returning an empty table.
template <class Keys, class Values>
UninitVector<std::uint32_t> sort_pairs_by_cell(Keys& keys, Values& values, double cells) {
  if (dense_cell_table(cells, keys.size()))
    return counting_sort_pairs(keys, values, std::size_t(cells));
  radix_sort_pairs(keys, values);
  return {};
}

}  // namespace slurry::io::detail
