#pragma once
// The checks on an oscillating drop (surface_tension_drop.h, oscillating_drop) that
// flip_surface_tension_tests and their validation set share.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "surface_tension_drop.h"

namespace slurry_test {

/// Prints and checks a mode-2 oscillation: at least `min_half_periods` half periods, the period
/// within 5% of Rayleigh's.
inline void check_rayleigh(const Oscillation& r, const char* what, int min_half_periods = 2) {
  std::printf("[ figure ] %s, mode 2, amplitude 5%%: period %.4f s, Rayleigh %.4f s, error %.3f%% (%d half periods)\n", what,
              r.period, r.rayleigh, 100 * (r.period / r.rayleigh - 1), r.half_periods);
  ASSERT_GE(r.half_periods, min_half_periods);
  EXPECT_LT(std::abs(r.period / r.rayleigh - 1), 0.05);
}

/// Prints and checks that a mode-2 oscillation keeps its amplitude, within [low, 1.2] of the
/// release's in every half period, and its particles together, none farther than 1.1 R from the
/// centre of mass (the release's spheroid reaches 1.05 R).
inline void check_sustained(const Oscillation& r, const char* what, double low) {
  std::printf("[ figure ] %s: amplitude of each half period over the release's:", what);
  for (double p : r.peaks) std::printf(" %.3f", p / std::abs(r.m0));
  std::printf("; farthest particle %.3f R\n", r.farthest);
  for (double p : r.peaks) {
    EXPECT_GT(p / std::abs(r.m0), low);
    EXPECT_LT(p / std::abs(r.m0), 1.2);
  }
  EXPECT_LT(r.farthest, 1.1);
}

}  // namespace slurry_test
