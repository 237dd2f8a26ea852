// The surfacer's radix sort (io/src/vdb/radix_sort.h) against std::stable_sort: keys with many
// ties over several of its chunks, on one and two threads.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <random>
#include <vector>

#include "slurry/transfer/parallel.h"
#include "vdb/radix_sort.h"

namespace {

void expect_stable_sort(std::size_t n, std::uint64_t key_range, int threads) {
  std::mt19937_64 rng(n + key_range);
  std::vector<std::uint64_t> keys(n);
  for (auto& k : keys) k = rng() % key_range;
  std::vector<std::uint32_t> values(n);
  std::iota(values.begin(), values.end(), 0u);
  std::vector<std::pair<std::uint64_t, std::uint32_t>> expected(n);
  for (std::size_t i = 0; i < n; ++i) expected[i] = {keys[i], values[i]};
  std::stable_sort(expected.begin(), expected.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  {
    const slurry::parallel::ThreadLimit limit(threads);
    slurry::io::detail::radix_sort_pairs(keys, values);
  }
  std::size_t wrong = 0;
  for (std::size_t i = 0; i < n; ++i) wrong += keys[i] != expected[i].first || values[i] != expected[i].second;
  EXPECT_EQ(wrong, 0u) << n << " pairs, keys below " << key_range << ", " << threads << " threads";
}

TEST(RadixSort, MatchesAStableSortOnOneAndTwoThreads) {
  for (const int threads : {1, 2}) {
    expect_stable_sort(0, 10, threads);
    expect_stable_sort(1000, 7, threads);                       // one chunk, ties
    expect_stable_sort(300000, 1000, threads);                  // five chunks, ties across them
    expect_stable_sort(300000, std::uint64_t(1) << 40, threads); // four passes
  }
}

}  // namespace
