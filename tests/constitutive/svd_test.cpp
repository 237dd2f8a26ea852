// Tests for constitutive/svd.h: the rotation-variant SVD and polar decomposition, 2x2 and 3x3,
// float and double, against their defining properties and against Eigen::JacobiSVD; and for
// svd_lanes.h, the batched 3x3 SVD, which runs the same SVD tests (cases with lanes = true).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <vector>

#include "slurry/constitutive/kinematics.h"
#include "slurry/constitutive/svd.h"
#include "slurry/constitutive/svd_lanes.h"
#include "test_util.h"

namespace {

constexpr double kPi = 3.14159265358979323846;

using slurry::constitutive::polar;
using slurry::constitutive::svd;

template <class T, int D, bool Lanes = false>
struct Case {
  using Scalar = T;
  static constexpr int dim = D;
  static constexpr bool lanes = Lanes;  ///< through svd_lanes.h instead of svd.h
};

/// Relative tolerance of every identity checked here. A backward-stable SVD gets
/// ||U S V^T - F|| ~ c eps ||F|| with c ~ 10 (measured: 3e-15 in double, 1.7e-6 in float over
/// 1e5 matrices of every kind below). 1e-12 (double) and 2e-5 (float) leave two orders of
/// margin while still failing for an unconverged method (e.g. McAdams' 4 approximate sweeps:
/// 2e-3 in the worst case).
template <class T>
double tol() {
  return std::is_same<T, float>::value ? 2e-5 : 1e-12;
}

template <int D>
Eigen::Matrix<double, D, D> random_rotation(std::mt19937& rng);

template <>
Eigen::Matrix2d random_rotation<2>(std::mt19937& rng) {
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  return Eigen::Rotation2Dd(angle(rng)).toRotationMatrix();
}

template <>
Eigen::Matrix3d random_rotation<3>(std::mt19937& rng) {
  std::normal_distribution<double> n;
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  return q.normalized().toRotationMatrix();
}

/// R1 diag(s) R2 with random rotations, computed in double.
template <int D>
Eigen::Matrix<double, D, D> with_singular_values(const Eigen::Matrix<double, D, 1>& s,
                                                 std::mt19937& rng) {
  return random_rotation<D>(rng) * s.asDiagonal() * random_rotation<D>(rng).transpose();
}

/// svd(F) of svd.h, or with Lanes that of svd_lanes.h: F in one lane (a different one at each
/// call) of a batch whose other lanes hold other matrices. The lanes version also checks that
/// F's bits come out the same in every lane (a batch filled with F).
template <class T, int D, bool Lanes>
void decompose(const Eigen::Matrix<T, D, D>& F, Eigen::Matrix<T, D, D>& U, Eigen::Matrix<T, D, 1>& sigma,
               Eigen::Matrix<T, D, D>& V) {
  if constexpr (!Lanes) {
    svd(F, U, sigma, V);
  } else {
    static_assert(D == 3, "svd_lanes.h is 3x3");
    namespace lanes = slurry::constitutive::lanes;
    constexpr int W = lanes::kWidth<T>;
    static int slot = 0;
    slot = (slot + 5) % W;
    lanes::Mat3<T, W> Fl, Ul, Vl;
    lanes::Vec3<T, W> sl;
    for (int l = 0; l < W; ++l) {
      Eigen::Matrix<T, 3, 3> other = Eigen::Matrix<T, 3, 3>::Identity();
      other(0, 1) = T(0.1 * l);
      other(2, 2) = T(l % 3 - 1);  // neighbours of every kind: singular, inverted, plain
      Fl.put(l, l == slot ? F : other);
    }
    lanes::svd(Fl, Ul, sl, Vl);
    U = Ul.get(slot);
    V = Vl.get(slot);
    for (int i = 0; i < 3; ++i) sigma(i) = sl.c[i][slot];
    for (int l = 0; l < W; ++l) Fl.put(l, F);
    lanes::svd(Fl, Ul, sl, Vl);
    for (int l = 0; l < W; ++l) {
      EXPECT_EQ(Ul.get(l), U) << "lane " << l;
      EXPECT_EQ(Vl.get(l), V) << "lane " << l;
      for (int i = 0; i < 3; ++i) EXPECT_EQ(sl.c[i][l], sigma(i)) << "lane " << l;
    }
  }
}

/// Checks every property of the decomposition of F (given in double, rounded to T) and returns
/// the relative reconstruction error.
template <class T, int D, bool Lanes = false>
double check_svd(const Eigen::Matrix<double, D, D>& F_in, const char* what) {
  using Mat = Eigen::Matrix<T, D, D>;
  using MatD = Eigen::Matrix<double, D, D>;
  const Mat F = F_in.template cast<T>();
  const MatD Fd = F.template cast<double>();  // the matrix actually decomposed
  Mat U, V;
  Eigen::Matrix<T, D, 1> sigma;
  decompose<T, D, Lanes>(F, U, sigma, V);
  const MatD Ud = U.template cast<double>(), Vd = V.template cast<double>();
  const Eigen::Matrix<double, D, 1> s = sigma.template cast<double>();
  const double scale = std::max(Fd.norm(), std::numeric_limits<double>::min());
  const double t = tol<T>();

  const double rec = (Ud * s.asDiagonal() * Vd.transpose() - Fd).norm() / scale;
  EXPECT_LT(rec, t) << what << ": reconstruction\nF =\n" << Fd;
  EXPECT_LT((Ud.transpose() * Ud - MatD::Identity()).norm(), t) << what << ": U orthogonal";
  EXPECT_LT((Vd.transpose() * Vd - MatD::Identity()).norm(), t) << what << ": V orthogonal";
  EXPECT_NEAR(Ud.determinant(), 1.0, t) << what << ": det U";
  EXPECT_NEAR(Vd.determinant(), 1.0, t) << what << ": det V";

  // Order: sigma_0 >= ... >= sigma_{D-2} >= |sigma_{D-1}|, all but the last non-negative.
  const double slack = t * scale;
  for (int i = 0; i + 1 < D; ++i) {
    EXPECT_GE(s(i), -slack) << what << ": sigma_" << i << " negative";
    EXPECT_GE(s(i) + slack, std::abs(s(i + 1))) << what << ": order at " << i;
  }
  // Values: the magnitudes agree with Eigen's SVD of the same matrix (in double).
  Eigen::JacobiSVD<MatD> ref(Fd);
  for (int i = 0; i < D; ++i)
    EXPECT_NEAR(std::abs(s(i)), ref.singularValues()(i), slack) << what << ": sigma_" << i;
  // Sign: the last singular value carries the sign of det F, whenever that sign is not lost in
  // round-off (|sigma_min| well above eps sigma_max).
  const double noise = 100 * std::numeric_limits<T>::epsilon() * ref.singularValues()(0);
  if (ref.singularValues()(D - 1) > noise) {
    EXPECT_EQ(s(D - 1) < 0, Fd.determinant() < 0) << what << ": sign of sigma_last\nF =\n" << Fd;
  }
  return rec;
}

template <class T, int D>
void check_polar(const Eigen::Matrix<double, D, D>& F_in, const char* what) {
  using Mat = Eigen::Matrix<T, D, D>;
  using MatD = Eigen::Matrix<double, D, D>;
  const Mat F = F_in.template cast<T>();
  const MatD Fd = F.template cast<double>();
  Mat R, S;
  polar(F, R, S);
  const MatD Rd = R.template cast<double>(), Sd = S.template cast<double>();
  const double scale = std::max(Fd.norm(), std::numeric_limits<double>::min());
  const double t = tol<T>();
  EXPECT_LT((Rd * Sd - Fd).norm() / scale, t) << what << ": R S = F";
  EXPECT_LT((Rd.transpose() * Rd - MatD::Identity()).norm(), t) << what << ": R orthogonal";
  EXPECT_NEAR(Rd.determinant(), 1.0, t) << what << ": det R";
  EXPECT_LT((Sd - Sd.transpose()).norm() / scale, t) << what << ": S symmetric";
  // Consistency with the SVD: R = U V^T, S = V diag(sigma) V^T. R is unique where F has at most
  // one zero singular value and sigma_{D-2} + sigma_{D-1} != 0; the inputs below are such.
  Mat U, V;
  Eigen::Matrix<T, D, 1> sigma;
  svd(F, U, sigma, V);
  const MatD UVt = (U * V.transpose()).template cast<double>();
  EXPECT_LT((UVt - Rd).norm(), 100 * t) << what << ": R = U V^T";
}

template <class C>
class SvdTest : public ::testing::Test {};
using Cases = ::testing::Types<Case<float, 2>, Case<double, 2>, Case<float, 3>, Case<double, 3>, Case<float, 3, true>,
                               Case<double, 3, true>>;
TYPED_TEST_SUITE(SvdTest, Cases);

TYPED_TEST(SvdTest, RandomMatrices) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  double worst = 0;
  for (int k = 0; k < 2000; ++k) {
    Eigen::Matrix<double, D, D> F;
    for (int i = 0; i < D * D; ++i) F(i) = u(rng);
    worst = std::max(worst, check_svd<T, D, TypeParam::lanes>(F, "random"));
    if (::testing::Test::HasFailure()) break;
  }
  ::testing::Test::RecordProperty("worst_reconstruction", std::to_string(worst));
}

TYPED_TEST(SvdTest, DeformationGradientsNearRotations) {
  // The MPM hot case: F = R1 diag(1 + small) R2; singular values nearly repeated.
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-1, 1);
  for (double spread : {1e-1, 1e-3, 1e-6, 1e-9}) {
    for (int k = 0; k < 300; ++k) {
      Eigen::Matrix<double, D, 1> s;
      for (int i = 0; i < D; ++i) s(i) = 1 + spread * u(rng);
      check_svd<T, D, TypeParam::lanes>(with_singular_values<D>(s, rng), "near rotation");
      if constexpr (!TypeParam::lanes) check_polar<T, D>(with_singular_values<D>(s, rng), "near rotation");
    }
  }
}

TYPED_TEST(SvdTest, NearlySingular) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.5, 2);
  for (int k = 0; k < 500; ++k) {
    Eigen::Matrix<double, D, 1> s;
    for (int i = 0; i < D; ++i) s(i) = u(rng);
    s(D - 1) = 1e-8;
    check_svd<T, D, TypeParam::lanes>(with_singular_values<D>(s, rng), "one singular value 1e-8");
    if (D == 3) {
      // Two small singular values of different sizes: F^T F cannot separate them, the final
      // 2x2 step of the 3x3 SVD must.
      s(1) = 1e-4 * u(rng);
      s(2) = 1e-7 * u(rng);
      check_svd<T, D, TypeParam::lanes>(with_singular_values<D>(s, rng), "two small singular values");
    }
  }
}

TYPED_TEST(SvdTest, SingularAndRankOne) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int k = 0; k < 500; ++k) {
    Eigen::Matrix<double, D, D> F;
    for (int i = 0; i < D * D; ++i) F(i) = u(rng);
    F.row(D - 1) = F.row(0);  // exactly singular: two equal rows
    check_svd<T, D, TypeParam::lanes>(F, "two equal rows");
    Eigen::Matrix<double, D, 1> a, b;
    for (int i = 0; i < D; ++i) {
      a(i) = u(rng);
      b(i) = u(rng);
    }
    check_svd<T, D, TypeParam::lanes>(a * b.transpose(), "rank one");
    check_svd<T, D, TypeParam::lanes>(Eigen::Matrix<double, D, D>::Zero(), "zero");
  }
  // Exactly representable rank deficiency, with zero columns and rows.
  Eigen::Matrix<double, D, D> F = Eigen::Matrix<double, D, D>::Zero();
  F(0, D - 1) = 2;
  check_svd<T, D, TypeParam::lanes>(F, "single entry");
  Eigen::Matrix<T, D, D> U, V;
  Eigen::Matrix<T, D, 1> sigma;
  decompose<T, D, TypeParam::lanes>(F.template cast<T>(), U, sigma, V);
  EXPECT_EQ(sigma(0), T(2));
  for (int i = 1; i < D; ++i) EXPECT_EQ(sigma(i), T(0));
}

TYPED_TEST(SvdTest, Inverted) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.3, 3);
  for (int k = 0; k < 1000; ++k) {
    Eigen::Matrix<double, D, 1> s;
    for (int i = 0; i < D; ++i) s(i) = u(rng);
    s(k % D) *= -1;  // one negative factor anywhere: det < 0
    const Eigen::Matrix<double, D, D> F = with_singular_values<D>(s, rng);
    ASSERT_LT(F.determinant(), 0);
    check_svd<T, D, TypeParam::lanes>(F, "inverted");
    if constexpr (!TypeParam::lanes) check_polar<T, D>(F, "inverted");
    Eigen::Matrix<T, D, D> U, V;
    Eigen::Matrix<T, D, 1> sigma;
    decompose<T, D, TypeParam::lanes>(F.template cast<T>(), U, sigma, V);
    EXPECT_LT(sigma(D - 1), 0);
  }
}

TYPED_TEST(SvdTest, IdentityRotationsAndReflections) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  using MatD = Eigen::Matrix<double, D, D>;
  std::mt19937 rng(6);
  check_svd<T, D, TypeParam::lanes>(MatD::Identity(), "identity");
  check_svd<T, D, TypeParam::lanes>(-MatD::Identity(), "minus identity");
  for (int k = 0; k < 200; ++k) {
    const MatD R = random_rotation<D>(rng);
    check_svd<T, D, TypeParam::lanes>(R, "rotation");
    if constexpr (!TypeParam::lanes) check_polar<T, D>(R, "rotation");
    Eigen::Matrix<T, D, D> U, V, Rp, S;
    Eigen::Matrix<T, D, 1> sigma;
    decompose<T, D, TypeParam::lanes>(R.template cast<T>(), U, sigma, V);
    for (int i = 0; i < D; ++i) EXPECT_NEAR(sigma(i), 1, tol<T>());
    // A reflection: det = -1, singular values (1, ..., 1, -1).
    MatD Q = R;
    Q.col(0) *= -1;
    decompose<T, D, TypeParam::lanes>(Q.template cast<T>(), U, sigma, V);
    for (int i = 0; i + 1 < D; ++i) EXPECT_NEAR(sigma(i), 1, tol<T>());
    EXPECT_NEAR(sigma(D - 1), -1, tol<T>());
    check_svd<T, D, TypeParam::lanes>(Q, "reflection");
  }
  // Identity: exact.
  Eigen::Matrix<T, D, D> U, V;
  Eigen::Matrix<T, D, 1> sigma;
  decompose<T, D, TypeParam::lanes>(Eigen::Matrix<T, D, D>::Identity(), U, sigma, V);
  EXPECT_EQ(sigma, (Eigen::Matrix<T, D, 1>::Ones()));
}

TYPED_TEST(SvdTest, RepeatedSingularValues) {
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(7);
  std::vector<Eigen::Matrix<double, D, 1>> cases;
  Eigen::Matrix<double, D, 1> s;
  s.setConstant(2);
  cases.push_back(s);
  s(D - 1) = 0.5;
  cases.push_back(s);
  s.setConstant(0.5);
  s(0) = 3;
  cases.push_back(s);
  s.setConstant(2);
  s(D - 1) = -2;
  cases.push_back(s);  // inverted, |sigma| all equal
  for (const auto& c : cases) {
    check_svd<T, D, TypeParam::lanes>(Eigen::Matrix<double, D, D>(c.asDiagonal()), "diagonal repeated");
    for (int k = 0; k < 100; ++k) check_svd<T, D, TypeParam::lanes>(with_singular_values<D>(c, rng), "repeated");
  }
}

TYPED_TEST(SvdTest, Scale) {
  // Deformation gradients are O(1), but nothing in the method depends on the scale within the
  // documented range.
  using T = typename TypeParam::Scalar;
  constexpr int D = TypeParam::dim;
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-1, 1);
  for (double scale : {1e-6, 1e-3, 1e3, 1e6}) {
    for (int k = 0; k < 100; ++k) {
      Eigen::Matrix<double, D, D> F;
      for (int i = 0; i < D * D; ++i) F(i) = scale * u(rng);
      check_svd<T, D, TypeParam::lanes>(F, "scaled");
    }
  }
}

TEST(Svd2x2, KnownDecomposition) {
  // F = Rot(a) diag(3, -1) Rot(b)^T: det < 0, so sigma = (3, -1) exactly as built.
  const double a = 0.3, b = -1.1;
  const Eigen::Matrix2d Ra = Eigen::Rotation2Dd(a).toRotationMatrix();
  const Eigen::Matrix2d Rb = Eigen::Rotation2Dd(b).toRotationMatrix();
  const Eigen::Matrix2d F = Ra * Eigen::Vector2d(3, -1).asDiagonal() * Rb.transpose();
  Eigen::Matrix2d U, V;
  Eigen::Vector2d sigma;
  svd(F, U, sigma, V);
  EXPECT_NEAR(sigma(0), 3, 1e-14);
  EXPECT_NEAR(sigma(1), -1, 1e-14);
  // With distinct |sigma|, U and V are unique up to a common sign of each column pair; as
  // rotations in 2D, up to a common rotation by pi.
  const double sign = U.col(0).dot(Ra.col(0)) > 0 ? 1 : -1;
  EXPECT_LT((U - sign * Ra).norm(), 1e-14);
  EXPECT_LT((V - sign * Rb).norm(), 1e-14);
}

TEST(Polar2x2, RotationAngle) {
  // R is the rotation by atan2(F10 - F01, F00 + F11).
  Eigen::Matrix2d F;
  F << 1.5, -0.4, 0.9, 0.7;
  Eigen::Matrix2d R, S;
  polar(F, R, S);
  const double angle = std::atan2(F(1, 0) - F(0, 1), F(0, 0) + F(1, 1));
  EXPECT_LT((R - Eigen::Rotation2Dd(angle).toRotationMatrix()).norm(), 1e-15);
  EXPECT_LT((R * S - F).norm(), 1e-15);
}

}  // namespace

namespace {
// polar_rotation (Newton, Higham 1986) agrees with the SVD polar factor for non-inverted F,
// including stretches of 3x and near-singular J, and falls back to the rotation-variant SVD
// (det R = +1) for inverted F.
template <class T, int Dim>
void check_polar_rotation(T tol) {
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (int trial = 0; trial < 500; ++trial) {
    Mat F;
    for (int i = 0; i < Dim * Dim; ++i) F.data()[i] = T((trial % 3 == 0 ? 1.5 : 0.3) * U(rng));
    F += Mat::Identity();
    if (trial % 5 == 0) F.col(0) *= T(-1);  // inverted
    if (trial % 7 == 0) F.col(1) *= T(0.01);  // nearly singular
    Mat R_ref, S, R;
    slurry::constitutive::polar(F, R_ref, S);
    slurry::constitutive::polar_rotation<T, Dim>(F, R);
    EXPECT_LT((R - R_ref).norm(), tol) << "trial " << trial << "\n" << F;
    EXPECT_NEAR(R.determinant(), T(1), tol);
  }
}
TEST(PolarRotation, MatchesSvdPolarDouble2D) { check_polar_rotation<double, 2>(1e-10); }
TEST(PolarRotation, MatchesSvdPolarDouble3D) { check_polar_rotation<double, 3>(1e-10); }
TEST(PolarRotation, MatchesSvdPolarFloat3D) { check_polar_rotation<float, 3>(2e-4); }
TEST(PolarRotation, MatchesSvdPolarFloat2D) {
  check_polar_rotation<float, 2>(2e-5);
}
// The 2D closed form's one degenerate input, F = [p q; q -p] (every rotation gives the same
// tr(R^T F) = 0), takes the SVD's rotation: still a rotation, and still F's polar factor.
// A reflection F: (F00 + F11, F10 - F01) vanishes, so polar_rotation falls back to the SVD,
// and every rotation maximises tr(R^T F) (it is 0 for all). What must hold is what defines the
// rotation-variant polar factor: R a rotation, S = R^T F symmetric, and tr(R^T F) at least that
// of any other rotation (360 sampled). The same for the reflection perturbed by +-1e-9, where the
// closed form runs on a vector of length 1e-9 and R flips between I and -I with its sign.
TEST(PolarRotation, DegenerateReflection2D) {
  for (const double eps : {0.0, 1e-9, -1e-9}) {
    Eigen::Matrix2d F, R;
    F << 0.6 + eps, 0.8, 0.8, -0.6;
    slurry::constitutive::polar_rotation<double, 2>(F, R);
    EXPECT_LT((R.transpose() * R - Eigen::Matrix2d::Identity()).norm(), 1e-14) << "eps " << eps;
    EXPECT_NEAR(R.determinant(), 1.0, 1e-14) << "eps " << eps;
    const Eigen::Matrix2d S = R.transpose() * F;
    EXPECT_NEAR(S(0, 1), S(1, 0), 1e-14) << "eps " << eps;
    for (int deg = 0; deg < 360; ++deg) {
      const double a = deg * M_PI / 180;
      Eigen::Matrix2d Q;
      Q << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
      EXPECT_LE((Q.transpose() * F).trace(), S.trace() + 1e-14) << "eps " << eps << ", " << deg << " degrees";
    }
  }
}
// svd_lanes.h's left_eigen, the factorisation of the batched sand projection: F F^T =
// U diag(lambda) U^T with M = U^T F, on the inputs that projection gives it (det F > 0,
// sigma_min^2 >= 1e-3 sigma_max^2): near rotations with repeated singular values, random
// stretches, and the extreme ratio. Checked against the singular values of the double F:
// U a rotation and F = U M to c eps; lambda_i = sigma_i^2 to c eps sigma_max sigma_i (its stated
// accuracy: relative eps sigma_max / sigma_i); the rows of M orthogonal to c eps sigma_max^2
// (U diagonalises F F^T); c = 16. Each lane alone in a batch of others, as in check_svd.
template <class T>
void check_left_eigen() {
  namespace lanes = slurry::constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  constexpr double c = 16 * double(std::numeric_limits<T>::epsilon());
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<Eigen::Matrix3d> inputs;
  for (double spread : {0.0, 1e-6, 1e-3, 0.3}) {
    for (int k = 0; k < 40 * W; ++k) {
      Eigen::Vector3d s;
      for (int i = 0; i < 3; ++i) s(i) = 1 + spread * u(rng);
      if (k % 5 == 0) s(1) = s(0);  // exactly repeated
      inputs.push_back(with_singular_values<3>(s, rng));
    }
  }
  for (int k = 0; k < 40 * W; ++k) {
    Eigen::Vector3d s(1, std::pow(10.0, -0.75 * (1 + u(rng))), std::sqrt(1e-3));  // down to the threshold
    inputs.push_back(std::exp(u(rng)) * with_singular_values<3>(s, rng));
  }
  for (std::size_t b0 = 0; b0 < inputs.size(); b0 += W) {
    lanes::Mat3<T, W> F, U, M;
    lanes::Vec3<T, W> lam;
    for (int l = 0; l < W; ++l) F.put(l, inputs[b0 + std::size_t(l)].template cast<T>());
    lanes::left_eigen(F, U, lam, M);
    for (int l = 0; l < W; ++l) {
      const Eigen::Matrix3d Fd = F.get(l).template cast<double>();  // the rounded input
      const Eigen::Matrix3d Ud = U.get(l).template cast<double>(), Md = M.get(l).template cast<double>();
      Eigen::Vector3d sigma = Eigen::JacobiSVD<Eigen::Matrix3d>(Fd).singularValues();  // decreasing
      Eigen::Vector3d got(double(lam.c[0][l]), double(lam.c[1][l]), double(lam.c[2][l]));
      std::sort(got.data(), got.data() + 3, std::greater<double>());
      const double smax = sigma(0);
      EXPECT_LT((Ud.transpose() * Ud - Eigen::Matrix3d::Identity()).norm(), c) << Fd;
      EXPECT_GT(Ud.determinant(), 0);
      EXPECT_LT((Ud * Md - Fd).norm(), c * Fd.norm()) << Fd;
      for (int i = 0; i < 3; ++i) {
        EXPECT_NEAR(got(i), sigma(i) * sigma(i), c * smax * sigma(i)) << "sigma_" << i << " of\n" << Fd;
        EXPECT_NEAR(double(lam.c[i][l]), Md.row(i).squaredNorm(), c * smax * smax);
        for (int j = i + 1; j < 3; ++j) EXPECT_LT(std::abs(Md.row(i).dot(Md.row(j))), c * smax * smax) << Fd;
      }
      if (::testing::Test::HasFailure()) return;
    }
  }
}
TEST(LeftEigenLanes, DiagonalisesFFtFloat) { check_left_eigen<float>(); }
TEST(LeftEigenLanes, DiagonalisesFFtDouble) { check_left_eigen<double>(); }

}  // namespace

// Regression: the 3D sand example (sand_column_3d) blew up because the 3x3 SVD returned NaN
// for a deformation gradient at rest, equal to the identity up to a few ulps: the rounded mean
// q of F^T F's diagonal left tr(F^T F - q I) as large as the spread p, the eigen formula (which
// assumes a traceless C) then found no eigenvector, V came out NaN and sigma 0, and the Hencky
// stress of such a particle was 2.4e7 Pa instead of ~0. This is the matrix that particle had.
TEST(Svd3x3, IdentityToAFewUlpsFromTheSandColumn) {
  Eigen::Matrix3f F;
  F << 0x1.fffffep-1f, 0x1p-23f, -0x1p-25f, -0x1.8p-24f, 0x1.fffffep-1f, -0x1p-25f, 0x1p-24f, 0.0f,
      0x1.fffffep-1f;
  check_svd<float, 3>(F.cast<double>(), "sand column particle");
  check_svd<float, 3, true>(F.cast<double>(), "sand column particle, batched");
}

// The same failure over many matrices of that kind: s I (s = 1, 0.75, 1.5) plus a few ulps on
// the diagonal (often the same on all three, as at rest) and fractions of an ulp off it. The
// code before the fix gave NaN for 1 float and 45 double matrices in 2e6 of these.
template <class T>
Eigen::Matrix<T, 3, 3> identity_to_a_few_ulps(std::mt19937& rng) {
  const int which = std::uniform_int_distribution<int>(0, 3)(rng);
  const T sc = which == 0 ? T(1) : (which == 1 ? T(0.75) : T(1.5));
  return slurry::test::near_identity_by_ulps<T>(rng, sc);
}

/// Counts the decompositions that are non-finite or inaccurate, and keeps the worst error of
/// the others.
template <class T>
struct SweepTally {
  int bad = 0;
  double worst = 0;
  void add(const Eigen::Matrix<T, 3, 3>& F, const Eigen::Matrix<T, 3, 3>& U, const Eigen::Matrix<T, 3, 1>& s,
           const Eigen::Matrix<T, 3, 3>& V) {
    const double e = double((U * s.asDiagonal() * V.transpose() - F).norm() / F.norm());
    if (!(e < tol<T>()) || !U.allFinite() || !V.allFinite()) ++bad;
    else worst = std::max(worst, e);
  }
  void expect_all_good() const {
    EXPECT_EQ(bad, 0) << "matrices with a non-finite or inaccurate decomposition";
    EXPECT_LT(worst, tol<T>());
  }
};

template <class T>
void check_identity_to_a_few_ulps(int count) {
  std::mt19937 rng(3);
  SweepTally<T> tally;
  for (int n = 0; n < count; ++n) {
    const Eigen::Matrix<T, 3, 3> F = identity_to_a_few_ulps<T>(rng);
    Eigen::Matrix<T, 3, 3> U, V;
    Eigen::Matrix<T, 3, 1> s;
    svd(F, U, s, V);
    tally.add(F, U, s, V);
  }
  tally.expect_all_good();
}
TEST(Svd3x3, IdentityToAFewUlpsFloat) { check_identity_to_a_few_ulps<float>(2000000); }
TEST(Svd3x3, IdentityToAFewUlpsDouble) { check_identity_to_a_few_ulps<double>(2000000); }

// The same matrices through the batched SVD (svd_lanes.h), a full batch of them at a time.
template <class T>
void check_identity_to_a_few_ulps_lanes(int count) {
  namespace lanes = slurry::constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  std::mt19937 rng(3);
  SweepTally<T> tally;
  for (int n = 0; n < count; n += W) {
    lanes::Mat3<T, W> F, U, V;
    lanes::Vec3<T, W> s;
    for (int l = 0; l < W; ++l) F.put(l, identity_to_a_few_ulps<T>(rng));
    lanes::svd(F, U, s, V);
    for (int l = 0; l < W; ++l)
      tally.add(F.get(l), U.get(l), Eigen::Matrix<T, 3, 1>(s.c[0][l], s.c[1][l], s.c[2][l]), V.get(l));
  }
  tally.expect_all_good();
}
TEST(Svd3x3Lanes, IdentityToAFewUlpsFloat) { check_identity_to_a_few_ulps_lanes<float>(2000000); }
TEST(Svd3x3Lanes, IdentityToAFewUlpsDouble) { check_identity_to_a_few_ulps_lanes<double>(2000000); }
