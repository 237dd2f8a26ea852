#pragma once
// Helpers shared by the constitutive tests.
#include <Eigen/Geometry>
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

}  // namespace slurry::test
