// The batched fixed corotated stress (fixed_corotated_lanes.h) against the scalar
// FixedCorotated::kirchhoff, lane by lane, on the deformations MPM meets: near the identity,
// rotated and stretched, nearly incompressible, close to the iteration's det F = 1e-2 cut, and
// those the scalar code hands to the SVD (inverted, singular, det F <= 1e-2).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fixed_corotated_lanes.h"
#include "test_util.h"

namespace {

using slurry::constitutive::FixedCorotated;
namespace lanes = slurry::constitutive::lanes;

/// A deformation gradient of kind k (0-5): R diag(s) Q^T with singular values by kind.
template <class T>
Eigen::Matrix<T, 3, 3> sample(std::mt19937& rng, int kind) {
  std::uniform_real_distribution<double> u(0, 1);
  const Eigen::Matrix3d R = slurry::test::random_rotation<3>(rng),
                        Q = slurry::test::random_rotation<3>(rng);
  Eigen::Vector3d s;
  switch (kind) {
    case 0:  // elastic, near rest
      for (int i = 0; i < 3; ++i) s[i] = 1 + 0.02 * (u(rng) - 0.5);
      break;
    case 1:  // stretched and squashed
      for (int i = 0; i < 3; ++i) s[i] = 0.3 + 2.7 * u(rng);
      break;
    case 2:  // just above the iteration's cut: det F in (1e-2, 2e-2]
      s << 0.2, 0.25, (0.01 + 0.01 * u(rng)) / 0.05;
      break;
    case 3:  // at or below the cut: the scalar code takes the SVD
      s << 0.2, 0.25, 0.2 * u(rng);
      break;
    case 4:  // inverted
      for (int i = 0; i < 3; ++i) s[i] = 0.5 + u(rng);
      s[2] = -s[2];
      break;
    default:  // rotation only
      s.setOnes();
      break;
  }
  return (R * s.asDiagonal() * Q.transpose()).cast<T>();
}

template <class T>
void check_fixed_corotated_lanes(T tol) {
  constexpr int W = lanes::kWidth<T>;
  std::mt19937 rng(20261126);
  std::uniform_real_distribution<double> h(0.5, 4.0);
  const T mu = T(3.8e4), lambda = T(5.7e4);
  int taken = 0, flagged = 0;
  for (int batch = 0; batch < 400; ++batch) {
    std::vector<Eigen::Matrix<T, 3, 3>> F(W);
    std::vector<T> mul(W), laml(W);
    for (int l = 0; l < W; ++l) {
      F[std::size_t(l)] = sample<T>(rng, (batch + l) % 6);
      const T factor = T(h(rng));
      mul[std::size_t(l)] = mu * factor;
      laml[std::size_t(l)] = lambda * factor;
    }
    auto run = [&](bool reversed, lanes::Mat3<T, W>& tau) {
      lanes::Mat3<T, W> Fl;
      lanes::Lane<T, W> ml, ll;
      for (int l = 0; l < W; ++l) {
        const auto k = std::size_t(reversed ? W - 1 - l : l);
        Fl.put(l, F[k]);
        ml[l] = mul[k];
        ll[l] = laml[k];
      }
      return lanes::fixed_corotated_kirchhoff(Fl, ml, ll, tau);
    };
    lanes::Mat3<T, W> tau, tau_rev;
    const auto scalar = run(false, tau);
    const auto scalar_rev = run(true, tau_rev);
    for (int l = 0; l < W; ++l) {
      const auto& Fp = F[std::size_t(l)];
      const bool to_svd = !(Fp.determinant() > T(1e-2));
      const bool flag = scalar.bits[l] != T(0);
      // The lanes must leave to the SVD every F that polar_rotation leaves to it for its
      // determinant, and keep every other (all of them converge in 8 iterations).
      EXPECT_EQ(flag, to_svd) << "lane " << l << " det " << Fp.determinant();
      EXPECT_EQ(flag, scalar_rev.bits[W - 1 - l] != T(0));
      if (flag) {
        ++flagged;
        continue;
      }
      ++taken;
      const Eigen::Matrix<T, 3, 3> expect =
          FixedCorotated<T, 3>{mul[std::size_t(l)], laml[std::size_t(l)]}.kirchhoff(Fp);
      const Eigen::Matrix<T, 3, 3> got = tau.get(l);
      // Relative agreement, or round-off of the cancelling F - R (near a rotation tau is
      // 2 mu (F - R) F^T, of the size of that round-off): 64 eps mu |F|^2 + 64 eps lambda |J|.
      const T eps = std::numeric_limits<T>::epsilon();
      const T cancel = T(64) * eps *
                       (mul[std::size_t(l)] * Fp.squaredNorm() +
                        laml[std::size_t(l)] * std::abs(Fp.determinant()));
      EXPECT_LE((got - expect).norm(), tol * expect.norm() + cancel) << "lane " << l << "\nF =\n"
                                                                     << Fp << "\nexpected\n"
                                                                     << expect << "\ngot\n"
                                                                     << got;
      // Lanes do not interact: the same F in another lane gives the same bits.
      EXPECT_TRUE((got.array() == tau_rev.get(W - 1 - l).array()).all()) << "lane " << l;
    }
  }
  EXPECT_GT(taken, 2000);
  EXPECT_GT(flagged, 400);
}

TEST(FixedCorotatedLanes, AgreesWithTheScalarStressFloat) {
  check_fixed_corotated_lanes<float>(2e-5f);
}
TEST(FixedCorotatedLanes, AgreesWithTheScalarStressDouble) {
  check_fixed_corotated_lanes<double>(1e-12);
}

}  // namespace
