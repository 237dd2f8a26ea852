// The ThreadSanitizer build's canary: two loops through slurry::parallel::parallel_for on two
// threads, one whose iterations write one shared counter (a data race TSan must report) and one
// whose iterations write their own elements, then read after the loop (no race: the loop's end is
// a barrier, which TSan learns from LLVM's OpenMP runtime through the Archer tool). Run with
// argument "race" or "clean"; ctest checks the report appears for the first and not the second,
// so that the tsan label's silence means the parallel tests are race-free, not that TSan is blind.
#include <cstdio>
#include <cstring>
#include <vector>

#include "slurry/transfer/parallel.h"

int main(int argc, char** argv) {
  const bool race = argc > 1 && std::strcmp(argv[1], "race") == 0;
  slurry::parallel::ThreadLimit limit(2);
  std::vector<long> own(4096, 0);
  long shared = 0;
  for (int round = 0; round < 8; ++round) {
    slurry::parallel::parallel_for(0, std::int64_t(own.size()), [&](std::int64_t i) {
      own[std::size_t(i)] += i;
      if (race) shared += i;
    });
    long sum = 0;
    for (long v : own) sum += v;  // after the loop: ordered by its barrier
    shared += sum % 2;
  }
  std::printf("%ld %ld\n", own[4095], shared);
  return 0;
}
