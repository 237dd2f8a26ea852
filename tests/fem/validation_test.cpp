// FEM validations too long for CI (ctest -L validation): the cantilever's first bending
// frequency within 5% of Euler-Bernoulli on the slender 2D beam and on the 3D beam.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "cantilever.h"

namespace {

using fem_test::cantilever_frequency;

// The slender case, L/h = 20 (Timoshenko corrections about 0.3%), 8 elements across.
TEST(FemCantileverValidation, FirstBendingFrequencySlender2D) {
  const auto r = cantilever_frequency<2>(1.0, 0.05, 8);
  std::printf("[ figure ] 2D cantilever L/h = 20, 8 elements across (%d triangles, %ld steps): omega_1 = %.5f rad/s, "
              "Euler-Bernoulli %.5f, error %+.2f%%\n",
              r.elements, r.steps, r.omega_measured, r.omega_euler_bernoulli, 100 * r.relative_error);
  EXPECT_LT(std::abs(r.relative_error), 0.05);
}

// 3D: square section, L/h = 10, five-tetrahedron cells, 6 elements across.
TEST(FemCantileverValidation, FirstBendingFrequency3D) {
  const auto r = cantilever_frequency<3>(1.0, 0.1, 6);
  std::printf("[ figure ] 3D cantilever L/h = 10, 6 elements across (%d tetrahedra, %ld steps): omega_1 = %.5f rad/s, "
              "Euler-Bernoulli %.5f, error %+.2f%%\n",
              r.elements, r.steps, r.omega_measured, r.omega_euler_bernoulli, 100 * r.relative_error);
  EXPECT_LT(std::abs(r.relative_error), 0.05);
}

}  // namespace
