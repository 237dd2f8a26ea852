#pragma once
// Helpers shared by the constitutive tests.
#include <Eigen/Geometry>
#include <limits>
#include <random>

namespace slurry::test {

constexpr double kPi = 3.14159265358979323846;

/// A uniformly random rotation (angle in 2D, normalised Gaussian quaternion in 3D).
template <int D>
Eigen::Matrix<double, D, D> random_rotation(std::mt19937& rng) {
  if constexpr (D == 2) {
    std::uniform_real_distribution<double> angle(-kPi, kPi);
    return Eigen::Rotation2Dd(angle(rng)).toRotationMatrix();
  } else {
    std::normal_distribution<double> n;
    return Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
  }
}

/// s I plus a few ulps: k ulp / 2 on the diagonal (the same k on all three diagonal entries
/// with probability 1/2, as for a particle at rest) and k ulp / 8 off it, k in [-4, 4]. The
/// deformation gradients on which the 3x3 SVD once returned NaN (svd.h).
template <class T>
Eigen::Matrix<T, 3, 3> near_identity_by_ulps(std::mt19937& rng, T s) {
  std::uniform_int_distribution<int> k(-4, 4), pick(0, 3);
  const T ulp = std::numeric_limits<T>::epsilon();
  const T shared = T(k(rng)) * ulp * T(0.5);
  const bool same = pick(rng) < 2;
  Eigen::Matrix<T, 3, 3> F;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      F(i, j) = i == j ? s + (same ? shared : T(k(rng)) * ulp * T(0.5)) : T(k(rng)) * ulp * T(0.125);
  return F;
}

}  // namespace slurry::test
