#pragma once
// A stable least-significant-digit radix sort of 64-bit keys with a 32-bit payload, 11 bits a
// pass over the bits the keys use: ties keep their order, so sorting (key, index) pairs emitted in
// index order sorts by key, then index, the same on any thread count.
#include <cstdint>
#include <utility>
#include <vector>

namespace slurry::io::detail {

inline void radix_sort_pairs(std::vector<std::uint64_t>& keys, std::vector<std::uint32_t>& values) {
  const std::size_t n = keys.size();
  std::uint64_t used = 0;
  for (const std::uint64_t k : keys) used |= k;
  constexpr int kDigit = 11;
  constexpr std::uint64_t kMask = (std::uint64_t(1) << kDigit) - 1;
  std::vector<std::uint64_t> keys_out(n);
  std::vector<std::uint32_t> values_out(n);
  std::vector<std::uint32_t> count(std::size_t(1) << kDigit);
  for (int shift = 0; shift < 64 && (used >> shift) != 0; shift += kDigit) {
    std::fill(count.begin(), count.end(), 0u);
    for (const std::uint64_t k : keys) ++count[std::size_t((k >> shift) & kMask)];
    std::uint32_t sum = 0;
    for (auto& c : count) sum += std::exchange(c, sum);
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t at = count[std::size_t((keys[i] >> shift) & kMask)]++;
      keys_out[at] = keys[i];
      values_out[at] = values[i];
    }
    keys.swap(keys_out);
    values.swap(values_out);
  }
}

}  // namespace slurry::io::detail
