#pragma once
// A stable least-significant-digit radix sort of 64-bit keys with a 32-bit payload, 11 bits a
// pass over the bits the keys use: ties keep their order, so sorting (key, index) pairs emitted in
// index order sorts by key, then index. A stable sort has one result, so the threads change only
// the time: each pass counts the digits of fixed chunks of the input in parallel, gives every
// (digit, chunk) its place in digit order then chunk order, and scatters the chunks in parallel,
// each in its own order.
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "slurry/transfer/parallel.h"

namespace slurry::io::detail {

/// Keys and Values: vectors of std::uint64_t and std::uint32_t (any allocator).
template <class Keys, class Values>
void radix_sort_pairs(Keys& keys, Values& values) {
  const std::size_t n = keys.size();
  constexpr int kDigit = 11;
  constexpr std::size_t kDigits = std::size_t(1) << kDigit;
  constexpr std::uint64_t kMask = kDigits - 1;
  constexpr std::size_t kChunk = std::size_t(1) << 16;
  const std::size_t chunks = std::max<std::size_t>(1, (n + kChunk - 1) / kChunk);
  const auto chunk_begin = [&](std::size_t c) { return std::min(n, c * kChunk); };
  std::vector<std::uint64_t> chunk_used(chunks, 0);
  slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
    std::uint64_t used = 0;
    for (std::size_t i = chunk_begin(std::size_t(c)); i < chunk_begin(std::size_t(c) + 1); ++i) used |= keys[i];
    chunk_used[std::size_t(c)] = used;
  });
  std::uint64_t used = 0;
  for (const std::uint64_t u : chunk_used) used |= u;
  if (used == 0) return;
  Keys keys_out(n);
  Values values_out(n);
  std::vector<std::uint32_t> count(chunks * kDigits);  // chunk c's digits at c * kDigits
  for (int shift = 0; shift < 64 && (used >> shift) != 0; shift += kDigit) {
    slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
      std::uint32_t* cc = count.data() + std::size_t(c) * kDigits;
      std::fill(cc, cc + kDigits, 0u);
      for (std::size_t i = chunk_begin(std::size_t(c)); i < chunk_begin(std::size_t(c) + 1); ++i)
        ++cc[std::size_t((keys[i] >> shift) & kMask)];
    });
    std::uint32_t sum = 0;
    for (std::size_t d = 0; d < kDigits; ++d)
      for (std::size_t c = 0; c < chunks; ++c) sum += std::exchange(count[c * kDigits + d], sum);
    slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
      std::uint32_t* cc = count.data() + std::size_t(c) * kDigits;
      for (std::size_t i = chunk_begin(std::size_t(c)); i < chunk_begin(std::size_t(c) + 1); ++i) {
        const std::uint32_t at = cc[std::size_t((keys[i] >> shift) & kMask)]++;
        keys_out[at] = keys[i];
        values_out[at] = values[i];
      }
    });
    keys.swap(keys_out);
    values.swap(values_out);
  }
}

}  // namespace slurry::io::detail
