#pragma once
// The (block, item) pairs of items that each cover a box of blocks, listed in item order, for
// sorting by block: counted per chunk of items in parallel, then each chunk writes its own
// stretch of the list (the list of one serial loop over the items).
#include <algorithm>
#include <cstdint>
#include <vector>

#include "slurry/transfer/parallel.h"
#include "vdb/buffer.h"

namespace slurry::io::detail {

/// For every item i of [0, n): box(i, b0, b1) sets its blocks' inclusive bounds per axis (empty
/// when b0 > b1 on an axis); key(x, y, z) is a block's key. Fills keys and items with a pair per
/// (block, item), in item order, then z, y, x.
template <class Box, class Key>
void list_block_pairs(std::size_t n, Box&& box, Key&& key, UninitVector<std::uint64_t>& keys,
                      UninitVector<std::uint32_t>& items) {
  constexpr std::size_t kChunk = std::size_t(1) << 13;
  const std::size_t chunks = (n + kChunk - 1) / kChunk;
  const auto chunk_end = [&](std::size_t c) { return std::min(n, (c + 1) * kChunk); };
  const auto blocks = [](const std::int64_t b0[3], const std::int64_t b1[3]) {
    std::size_t count = 1;
    for (int d = 0; d < 3; ++d) count *= b1[d] >= b0[d] ? std::size_t(b1[d] - b0[d] + 1) : 0;
    return count;
  };
  std::vector<std::size_t> start(chunks + 1, 0);
  slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
    std::size_t pairs = 0;
    std::int64_t b0[3], b1[3];
    for (std::size_t i = std::size_t(c) * kChunk; i < chunk_end(std::size_t(c)); ++i) box(i, b0, b1), pairs += blocks(b0, b1);
    start[std::size_t(c) + 1] = pairs;
  });
  for (std::size_t c = 0; c < chunks; ++c) start[c + 1] += start[c];
  keys.resize(start[chunks]);
  items.resize(start[chunks]);
  slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
    std::size_t at = start[std::size_t(c)];
    std::int64_t b0[3], b1[3];
    for (std::size_t i = std::size_t(c) * kChunk; i < chunk_end(std::size_t(c)); ++i) {
      box(i, b0, b1);
      if (blocks(b0, b1) == 0) continue;
      for (std::int64_t z = b0[2]; z <= b1[2]; ++z)
        for (std::int64_t y = b0[1]; y <= b1[1]; ++y)
          for (std::int64_t x = b0[0]; x <= b1[0]; ++x) keys[at] = key(x, y, z), items[at++] = std::uint32_t(i);
    }
  });
}

}  // namespace slurry::io::detail
