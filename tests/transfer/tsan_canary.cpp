// The ThreadSanitizer build's canary: a loop through slurry::parallel::parallel_tasks on two
// threads whose two tasks meet (each waits, up to 10 s, until both have started, so that both
// threads take part whatever the scheduling) and then either write one shared counter (argument
// "race": a data race TSan must report) or only their own elements, read after the loop (argument
// "clean": no race, the loop's end is a barrier, which TSan learns from LLVM's OpenMP runtime
// through the Archer tool). ctest checks the report appears for the first and not the second, so
// that the tsan tests' silence means the parallel code is race-free, not that TSan is blind.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <vector>

#include "slurry/transfer/parallel.h"

int main(int argc, char** argv) {
  const bool race = argc > 1 && std::strcmp(argv[1], "race") == 0;
  slurry::parallel::ThreadLimit limit(2);
  std::vector<long> own(2, 0);
  long shared = 0;
  std::atomic<int> arrived{0};
  slurry::parallel::parallel_tasks(0, 2, [&](std::int64_t i) {
    arrived.fetch_add(1);
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (arrived.load() < 2 && std::chrono::steady_clock::now() < until) {
    }
    own[std::size_t(i)] += i + 1;
    if (race) shared += i + 1;
  });
  shared += own[0] + own[1];  // after the loop: ordered by its barrier
  std::printf("%ld, %d threads met\n", shared, arrived.load());
  return 0;
}
