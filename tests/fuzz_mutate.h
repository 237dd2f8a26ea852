// The mutation step shared by the fuzzers (tests/io/fuzz_test.cpp, tests/run/state_fuzz_test.cpp).
#pragma once
#include <cstddef>
#include <random>
#include <string>

namespace slurry::test {

/// One mutated copy of `seed`: 1-4 mutations, each at a random place: a flipped bit, a deletion,
/// a duplicated range, a truncation, a random byte, or `special(s, at, pick)`, the fuzzer's own
/// (tokens that once broke a text reader, integers that mislead a binary one); `pick(n)` draws
/// an index below n. The draws come from `rng` alone, so a seed reproduces every input.
template <class Special>
std::string mutate(const std::string& seed, std::mt19937_64& rng, Special&& special) {
  std::string s = seed;
  const auto pick = [&](std::size_t n) { return n == 0 ? std::size_t(0) : std::size_t(rng() % n); };
  const int n = 1 + int(rng() % 4);
  for (int k = 0; k < n; ++k) {
    const std::size_t at = pick(s.size() + 1);
    switch (rng() % 6) {
      case 0:  // flip a bit
        if (!s.empty()) s[pick(s.size())] ^= char(1 << (rng() % 8));
        break;
      case 1:
        special(s, at, pick);
        break;
      case 2:  // delete a range
        s.erase(at, pick(32) + 1);
        break;
      case 3: {  // duplicate a range
        const std::string part = s.substr(at, pick(64) + 1);
        s.insert(pick(s.size() + 1), part);
        break;
      }
      case 4:  // truncate
        s.resize(at);
        break;
      default:  // a random byte
        s.insert(at, 1, char(rng() % 256));
        break;
    }
  }
  return s;
}

}  // namespace slurry::test
