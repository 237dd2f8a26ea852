// Shared helpers of the FEM tests: irregular meshes and random rotations.
#pragma once
#include <Eigen/Geometry>

#include <cmath>
#include <random>

#include "slurry/engine/fem/mesh.h"

namespace fem_test {

/// A structured mesh of [0, 1]^Dim with `n` cells per axis whose interior vertices are moved
/// by up to `jitter` cells in each direction (seeded): an irregular mesh with a flat boundary.
template <int Dim>
slurry::fem::Mesh<Dim> irregular_box(int n, double jitter, unsigned seed = 7) {
  using V = Eigen::Matrix<double, Dim, 1>;
  auto m = slurry::fem::box_mesh<Dim>(V::Zero(), V::Ones(), Eigen::Matrix<int, Dim, 1>::Constant(n));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter / n, jitter / n);
  for (auto& x : m.x) {
    bool interior = true;
    for (int d = 0; d < Dim; ++d) interior = interior && x[d] > 1e-12 && x[d] < 1 - 1e-12;
    if (interior)
      for (int d = 0; d < Dim; ++d) x[d] += u(rng);
  }
  slurry::fem::check_mesh(m, "irregular_box");
  return m;
}

/// True if vertex x of the unit box lies on its boundary.
template <class V>
bool on_unit_box_boundary(const V& x) {
  for (int d = 0; d < x.size(); ++d)
    if (x[d] < 1e-12 || x[d] > 1 - 1e-12) return true;
  return false;
}

/// A uniformly random rotation (2D: an angle; 3D: a normalised Gaussian quaternion).
template <int Dim>
Eigen::Matrix<double, Dim, Dim> random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> g;
  if constexpr (Dim == 2) {
    const double a = std::uniform_real_distribution<double>(-M_PI, M_PI)(rng);
    return Eigen::Rotation2Dd(a).toRotationMatrix();
  } else {
    Eigen::Quaterniond q(g(rng), g(rng), g(rng), g(rng));
    return q.normalized().toRotationMatrix();
  }
}

}  // namespace fem_test
