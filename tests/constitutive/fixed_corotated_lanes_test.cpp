// The batched fixed corotated stress (fixed_corotated_lanes.h), 3D and 2D, against the scalar
// FixedCorotated::kirchhoff, lane by lane, on the deformations MPM meets: near the identity,
// rotated and stretched, nearly incompressible, close to the iteration's det F = 1e-2 cut, and
// those the scalar code hands to the SVD (inverted, singular, det F <= 1e-2).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <type_traits>
#include <vector>

#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fixed_corotated_lanes.h"
#include "test_util.h"

namespace {

using slurry::constitutive::FixedCorotated;
namespace lanes = slurry::constitutive::lanes;

/// A deformation gradient of kind k (0-5): R diag(s) Q^T with singular values by kind.
template <class T, int Dim>
Eigen::Matrix<T, Dim, Dim> sample(std::mt19937& rng, int kind) {
  using VecD = Eigen::Matrix<double, Dim, 1>;
  using MatD = Eigen::Matrix<double, Dim, Dim>;
  std::uniform_real_distribution<double> u(0, 1);
  const MatD R = slurry::test::random_rotation<Dim>(rng),
             Q = slurry::test::random_rotation<Dim>(rng);
  VecD s;
  // The other singular values' product, so that the last one sets det F.
  const double others = Dim == 3 ? 0.2 * 0.25 : 0.2;
  switch (kind) {
    case 0:  // elastic, near rest
      for (int i = 0; i < Dim; ++i) s[i] = 1 + 0.02 * (u(rng) - 0.5);
      break;
    case 1:  // stretched and squashed
      for (int i = 0; i < Dim; ++i) s[i] = 0.3 + 2.7 * u(rng);
      break;
    case 2:  // just above the iteration's cut: det F in (1e-2, 2e-2]
      if constexpr (Dim == 3) {
        s << 0.2, 0.25, (0.01 + 0.01 * u(rng)) / others;
      } else {
        // Equal singular values: with 0.2 and 0.05, double needs a 9th Newton iteration and
        // the scalar code (rightly) goes to the SVD; the test wants F that converge.
        s.setConstant(std::sqrt(0.01 + 0.01 * u(rng)));
      }
      break;
    case 3:  // at or below the cut: the scalar code takes the SVD
      for (int i = 0; i + 1 < Dim; ++i) s[i] = i == 0 ? 0.2 : 0.25;
      s[Dim - 1] = 0.01 * u(rng) / others;
      break;
    case 4:  // inverted
      for (int i = 0; i < Dim; ++i) s[i] = 0.5 + u(rng);
      s[Dim - 1] = -s[Dim - 1];
      break;
    default:  // rotation only
      s.setOnes();
      break;
  }
  return (R * s.asDiagonal() * Q.transpose()).template cast<T>();
}

template <class T, int Dim>
void check_fixed_corotated_lanes(T tol) {
  constexpr int W = lanes::kWidth<T>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using MatL = std::conditional_t<Dim == 3, lanes::Mat3<T, W>, lanes::Mat2<T, W>>;
  std::mt19937 rng(20261126);
  std::uniform_real_distribution<double> h(0.5, 4.0);
  const T mu = T(3.8e4), lambda = T(5.7e4);
  int taken = 0, flagged = 0;
  for (int batch = 0; batch < 400; ++batch) {
    std::vector<Mat> F(W);
    std::vector<T> mul(W), laml(W);
    for (int l = 0; l < W; ++l) {
      F[std::size_t(l)] = sample<T, Dim>(rng, (batch + l) % 6);
      // 2D: the closed form's one degenerate input, F = [p q; q -p], in lane 0 of every 10th
      // batch (it goes to the SVD).
      if constexpr (Dim == 2)
        if (l == 0 && batch % 10 == 0) F[0] << T(0.6), T(0.8), T(0.8), T(-0.6);
      const T factor = T(h(rng));
      mul[std::size_t(l)] = mu * factor;
      laml[std::size_t(l)] = lambda * factor;
    }
    auto run = [&](bool reversed, MatL& tau) {
      MatL Fl;
      lanes::Lane<T, W> ml, ll;
      for (int l = 0; l < W; ++l) {
        const auto k = std::size_t(reversed ? W - 1 - l : l);
        Fl.put(l, F[k]);
        ml[l] = mul[k];
        ll[l] = laml[k];
      }
      return lanes::fixed_corotated_kirchhoff(Fl, ml, ll, tau);
    };
    MatL tau, tau_rev;
    const auto scalar = run(false, tau);
    const auto scalar_rev = run(true, tau_rev);
    for (int l = 0; l < W; ++l) {
      const auto& Fp = F[std::size_t(l)];
      // The lanes must leave to the SVD every F that polar_rotation leaves to it, and keep every
      // other: in 3D for its determinant (all the others converge in 8 iterations), in 2D where
      // the closed form's vector vanishes.
      const T a = Fp(0, 0) + Fp(Dim - 1, Dim - 1), b = Fp(Dim - 1, 0) - Fp(0, Dim - 1);
      const bool to_svd = Dim == 3 ? !(Fp.determinant() > T(1e-2))
                                   : !(a * a + b * b >= std::numeric_limits<T>::min());
      const bool flag = scalar.bits[l] != T(0);
      EXPECT_EQ(flag, to_svd) << "lane " << l << " det " << Fp.determinant();
      EXPECT_EQ(flag, scalar_rev.bits[W - 1 - l] != T(0));
      if (flag) {
        ++flagged;
        continue;
      }
      ++taken;
      const Mat expect =
          FixedCorotated<T, Dim>{mul[std::size_t(l)], laml[std::size_t(l)]}.kirchhoff(Fp);
      const Mat got = tau.get(l);
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
  EXPECT_GT(flagged, Dim == 3 ? 400 : 39);
}

TEST(FixedCorotatedLanes, AgreesWithTheScalarStressFloat) {
  check_fixed_corotated_lanes<float, 3>(2e-5f);
}
TEST(FixedCorotatedLanes, AgreesWithTheScalarStressDouble) {
  check_fixed_corotated_lanes<double, 3>(1e-12);
}
TEST(FixedCorotatedLanes, AgreesWithTheScalarStress2DFloat) {
  check_fixed_corotated_lanes<float, 2>(2e-5f);
}
TEST(FixedCorotatedLanes, AgreesWithTheScalarStress2DDouble) {
  check_fixed_corotated_lanes<double, 2>(1e-12);
}

}  // namespace
