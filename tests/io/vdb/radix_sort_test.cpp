// The surfacer's sorts against std::stable_sort: the radix sort (io/src/vdb/radix_sort.h), keys
// with many ties over several of its chunks, and the counting sort by cell with each cell's start
// (io/src/vdb/cell_starts.h), empty cells included; on one, two and three threads.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <random>
#include <vector>

#include "slurry/transfer/parallel.h"
#include "vdb/cell_starts.h"
#include "vdb/radix_sort.h"

namespace {

/// Sorts n random keys below key_range (radix, or counting with key_range cells) on `threads`
/// threads and compares with std::stable_sort; the counting sort's cell starts with the sorted
/// keys' lower bounds.
void expect_stable_sort(std::size_t n, std::uint64_t key_range, int threads, bool counting = false) {
  std::mt19937_64 rng(n + key_range);
  std::vector<std::uint64_t> keys(n);
  for (auto& k : keys) k = rng() % key_range;
  std::vector<std::uint32_t> values(n);
  std::iota(values.begin(), values.end(), 0u);
  std::vector<std::pair<std::uint64_t, std::uint32_t>> expected(n);
  for (std::size_t i = 0; i < n; ++i) expected[i] = {keys[i], values[i]};
  std::stable_sort(expected.begin(), expected.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  slurry::io::detail::UninitVector<std::uint32_t> first;
  {
    const slurry::parallel::ThreadLimit limit(threads);
    if (counting)
      first = slurry::io::detail::counting_sort_pairs(keys, values, std::size_t(key_range));
    else
      slurry::io::detail::radix_sort_pairs(keys, values);
  }
  std::size_t wrong = 0;
  for (std::size_t i = 0; i < n; ++i)
    wrong += keys[i] != expected[i].first || values[i] != expected[i].second;
  EXPECT_EQ(wrong, 0u) << n << " pairs, keys below " << key_range << ", " << threads << " threads";
  if (!counting) return;
  ASSERT_EQ(first.size(), std::size_t(key_range) + 1);
  std::size_t wrong_starts = 0;
  for (std::uint64_t k = 0; k <= key_range; ++k) {
    const auto at = std::lower_bound(expected.begin(), expected.end(), k,
                                     [](const auto& e, std::uint64_t key) { return e.first < key; });
    wrong_starts += first[std::size_t(k)] != std::uint32_t(at - expected.begin());
  }
  EXPECT_EQ(wrong_starts, 0u) << n << " pairs, " << key_range << " cells, " << threads << " threads";
}

TEST(RadixSort, MatchesAStableSortOnOneAndTwoThreads) {
  for (const int threads : {1, 2}) {
    expect_stable_sort(0, 10, threads);
    expect_stable_sort(1000, 7, threads);                       // one chunk, ties
    expect_stable_sort(300000, 1000, threads);                  // five chunks, ties across them
    expect_stable_sort(300000, std::uint64_t(1) << 40, threads); // four passes
  }
}

TEST(CountingSort, MatchesAStableSortAndFindsEachCellsStart) {
  for (const int threads : {1, 2, 3}) {
    expect_stable_sort(0, 10, threads, true);
    expect_stable_sort(1, 1, threads, true);
    expect_stable_sort(1000, 7, threads, true);          // every cell full, ties across the parts
    expect_stable_sort(1000, 5000, threads, true);       // most cells empty
    expect_stable_sort(300000, 200000, threads, true);   // several ranges of cells
  }
}

}  // namespace
