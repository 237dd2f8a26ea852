// Tests for the elastic models of constitutive/: stress against finite differences of energy,
// dP against finite differences of stress, tau = P F^T, rest state, objectivity, and agreement
// with linear elasticity at small strain.
#include <gtest/gtest.h>

#include "test_util.h"

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "slurry/constitutive/corotated_linear.h"
#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fluid.h"
#include "slurry/constitutive/hencky_stvk.h"
#include "slurry/constitutive/lame.h"
#include "slurry/constitutive/neo_hookean.h"
#include "slurry/constitutive/stvk.h"

namespace {

using slurry::test::kPi;
using slurry::test::random_rotation;

namespace sc = slurry::constitutive;

// Stiffnesses of order one: every check below is relative, and mu != lambda catches a swap.
constexpr double kMu = 3.0;
constexpr double kLambda = 5.0;
constexpr double kBulk = 4.0;

template <class M>
struct IsFluid : std::false_type {};
template <class T, int D>
struct IsFluid<sc::WeaklyCompressibleFluid<T, D>> : std::true_type {};

/// The same model template with float scalars.
template <class M>
struct RebindFloat;
template <template <class, int> class Model, int D>
struct RebindFloat<Model<double, D>> {
  using type = Model<float, D>;
};

template <class M>
M make_model() {
  using T = typename M::Scalar;
  if constexpr (IsFluid<M>::value)
    return M{T(kBulk), T(7)};
  else
    return M{T(kMu), T(kLambda)};
}


/// Test deformation gradients, all with J in [0.5, 2]: near the identity, moderately deformed
/// with random rotations, and with exactly repeated singular values (where the SVD-based
/// differentials have removable 0/0 singularities).
template <int D>
std::vector<Eigen::Matrix<double, D, D>> test_deformations() {
  using Mat = Eigen::Matrix<double, D, D>;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<Mat> out;
  for (int k = 0; k < 5; ++k) {
    Mat F = Mat::Identity();
    for (int i = 0; i < D * D; ++i) F(i) += 0.05 * u(rng);
    out.push_back(F);
  }
  while (out.size() < 15) {
    Eigen::Matrix<double, D, 1> s;
    for (int i = 0; i < D; ++i) s(i) = std::exp(0.4 * u(rng));
    const double J = s.prod();
    if (J < 0.5 || J > 2) continue;
    out.push_back(random_rotation<D>(rng) * s.asDiagonal() * random_rotation<D>(rng).transpose());
  }
  Eigen::Matrix<double, D, 1> s;
  s.setConstant(1.1);
  s(D - 1) = 0.8;
  out.push_back(random_rotation<D>(rng) * s.asDiagonal() * random_rotation<D>(rng).transpose());
  s.setConstant(0.9);
  out.push_back(random_rotation<D>(rng) * s.asDiagonal() * random_rotation<D>(rng).transpose());
  return out;
}

template <class M>
class ModelTest : public ::testing::Test {};

using Models = ::testing::Types<
    sc::FixedCorotated<double, 2>, sc::FixedCorotated<double, 3>, sc::CorotatedLinear<double, 2>,
    sc::CorotatedLinear<double, 3>, sc::NeoHookean<double, 2>, sc::NeoHookean<double, 3>,
    sc::StVenantKirchhoff<double, 2>, sc::StVenantKirchhoff<double, 3>, sc::HenckyStVK<double, 2>,
    sc::HenckyStVK<double, 3>, sc::WeaklyCompressibleFluid<double, 2>,
    sc::WeaklyCompressibleFluid<double, 3>>;
TYPED_TEST_SUITE(ModelTest, Models);

// Central differences with step h have truncation error ~h^2 |psi'''| ~ 1e-10 and round-off
// ~eps |psi| / h ~ 1e-11 here (|psi| and its derivatives are O(10)), far below the required
// relative 1e-5; a wrong term in P or dP is O(1) relative.
constexpr double kStep = 1e-5;
constexpr double kFdTol = 1e-5;

TYPED_TEST(ModelTest, PiolaIsEnergyGradient) {
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  for (const auto& F : test_deformations<D>()) {
    Eigen::Matrix<double, D, D> P_fd;
    for (int i = 0; i < D * D; ++i) {
      Eigen::Matrix<double, D, D> Fp = F, Fm = F;
      Fp(i) += kStep;
      Fm(i) -= kStep;
      P_fd(i) = (model.energy(Fp) - model.energy(Fm)) / (2 * kStep);
    }
    const Eigen::Matrix<double, D, D> P = model.piola(F);
    EXPECT_LT((P - P_fd).norm(), kFdTol * P.norm()) << "F =\n"
                                                    << F << "\nP =\n"
                                                    << P << "\nFD =\n"
                                                    << P_fd;
  }
}

TYPED_TEST(ModelTest, DifferentialMatchesFiniteDifferenceOfPiola) {
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(-1, 1);
  for (const auto& F : test_deformations<D>()) {
    for (int k = 0; k < 3; ++k) {
      Eigen::Matrix<double, D, D> dF;
      for (int i = 0; i < D * D; ++i) dF(i) = u(rng);
      dF.normalize();
      const Eigen::Matrix<double, D, D> fd =
          (model.piola(F + kStep * dF) - model.piola(F - kStep * dF)) / (2 * kStep);
      const Eigen::Matrix<double, D, D> dP = model.dP(F, dF);
      EXPECT_LT((dP - fd).norm(), kFdTol * dP.norm()) << "F =\n"
                                                      << F << "\ndP =\n"
                                                      << dP << "\nFD =\n"
                                                      << fd;
    }
  }
}

TYPED_TEST(ModelTest, KirchhoffIsPiolaTimesFTransposed) {
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  for (const auto& F : test_deformations<D>()) {
    const Eigen::Matrix<double, D, D> tau = model.kirchhoff(F);
    const Eigen::Matrix<double, D, D> PFt = model.piola(F) * F.transpose();
    // Two evaluations of the same closed form, each accurate to a few eps (the SVD to ~1e-15).
    EXPECT_LT((tau - PFt).norm(), 1e-12 * (1 + PFt.norm())) << "F =\n" << F;
    // tau is symmetric (balance of angular momentum).
    EXPECT_LT((tau - tau.transpose()).norm(), 1e-12 * (1 + tau.norm()));
  }
}

TYPED_TEST(ModelTest, RestStateIsStressFree) {
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  const Eigen::Matrix<double, D, D> I = Eigen::Matrix<double, D, D>::Identity();
  EXPECT_NEAR(model.energy(I), 0, 1e-14);
  EXPECT_LT(model.piola(I).norm(), 1e-14);
  EXPECT_LT(model.kirchhoff(I).norm(), 1e-14);
  // Energy grows away from the rest state (a minimum, not just a critical point).
  for (const auto& F : test_deformations<D>()) EXPECT_GT(model.energy(F), 0);
}

TYPED_TEST(ModelTest, Objectivity) {
  // psi(R F) = psi(F) and P(R F) = R P(F) for every rotation R.
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  std::mt19937 rng(13);
  for (const auto& F : test_deformations<D>()) {
    const Eigen::Matrix<double, D, D> R = random_rotation<D>(rng);
    const double psi = model.energy(F);
    EXPECT_NEAR(model.energy(R * F), psi, 1e-12 * (1 + std::abs(psi)));
    const Eigen::Matrix<double, D, D> P = model.piola(F);
    EXPECT_LT((model.piola(R * F) - R * P).norm(), 1e-12 * (1 + P.norm()));
    const Eigen::Matrix<double, D, D> tau = model.kirchhoff(F);
    EXPECT_LT((model.kirchhoff(R * F) - R * tau * R.transpose()).norm(), 1e-12 * (1 + tau.norm()));
  }
}

TYPED_TEST(ModelTest, SmallStrainLimitIsLinearElasticity) {
  // F = I + e with symmetric e of size 1e-6: P = 2 mu e + lambda tr(e) I + O(|e|^2) for the
  // solids, P = K tr(e) I for the fluid (K the bulk modulus). Relative error O(|e|) = 1e-6.
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  std::mt19937 rng(14);
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Matrix<double, D, D> e;
  for (int i = 0; i < D * D; ++i) e(i) = u(rng);
  e = (1e-6 * (e + e.transpose()) / 2).eval();  // eval: e.transpose() aliases e
  const Eigen::Matrix<double, D, D> I = Eigen::Matrix<double, D, D>::Identity();
  Eigen::Matrix<double, D, D> expected;
  if constexpr (IsFluid<M>::value)
    expected = kBulk * e.trace() * I;
  else
    expected = 2 * kMu * e + kLambda * e.trace() * I;
  EXPECT_LT((model.piola(I + e) - expected).norm(), 1e-5 * expected.norm());
}

TYPED_TEST(ModelTest, ScaledMultipliesStress) {
  using M = TypeParam;
  constexpr int D = M::dim;
  const M model = make_model<M>();
  const M stiffer = model.scaled(2.5);
  for (const auto& F : test_deformations<D>()) {
    const Eigen::Matrix<double, D, D> P = model.piola(F);
    EXPECT_LT((stiffer.piola(F) - 2.5 * P).norm(), 1e-13 * P.norm());
    EXPECT_NEAR(stiffer.energy(F), 2.5 * model.energy(F), 1e-13 * model.energy(F));
  }
}

TYPED_TEST(ModelTest, FloatInstantiationAgreesWithDouble) {
  // The engine runs in float too: the float model must compile and agree to float precision
  // (relative 1e-4 allows for the conditioning of the SVD-based models).
  using M = TypeParam;
  constexpr int D = M::dim;
  using Mf = typename RebindFloat<M>::type;
  const M model = make_model<M>();
  const Mf model_f = make_model<Mf>();
  for (const auto& F : test_deformations<D>()) {
    const Eigen::Matrix<float, D, D> Ff = F.template cast<float>();
    const Eigen::Matrix<double, D, D> Fd = Ff.template cast<double>();
    const Eigen::Matrix<float, D, D> tau_f = model_f.kirchhoff(Ff);
    EXPECT_TRUE(model_f.piola(Ff).allFinite());
    EXPECT_TRUE(model_f.dP(Ff, Eigen::Matrix<float, D, D>::Identity()).allFinite());
    EXPECT_TRUE(std::isfinite(model_f.energy(Ff)));
    const Eigen::Matrix<double, D, D> tau = model.kirchhoff(Fd);
    EXPECT_LT((tau_f.template cast<double>() - tau).norm(), 1e-4 * (1 + tau.norm()));
  }
}

// --- model-specific checks -------------------------------------------------------------------

TEST(Lame, FromYoungAndPoisson) {
  const auto l = sc::lame_from_young(1e6, 0.3);
  EXPECT_NEAR(l.mu, 1e6 / 2.6, 1e-9);
  EXPECT_NEAR(l.lambda, 3e5 / (1.3 * 0.4), 1e-9);
  // Wave speed sqrt((lambda + 2 mu) / rho) for rho = 1000.
  EXPECT_NEAR(sc::wave_speed(l, 1000.0), std::sqrt((l.lambda + 2 * l.mu) / 1000.0), 1e-12);
  EXPECT_NEAR(sc::wave_speed(sc::Lame<double>{1.0, 2.0}, 4.0), 1.0, 1e-15);
  EXPECT_THROW(sc::lame_from_young(1e6, 0.5), std::invalid_argument);
  EXPECT_THROW(sc::lame_from_young(-1.0, 0.3), std::invalid_argument);
  try {
    sc::lame_from_young(1e6, 0.7);
    FAIL() << "expected a throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("poisson_ratio = 0.7"), std::string::npos) << e.what();
  }
}

TEST(Validate, NamesFieldAndValue) {
  EXPECT_NO_THROW((sc::FixedCorotated<double, 3>{1, 1}.validate()));
  try {
    sc::NeoHookean<double, 3>{-2, 1}.validate();
    FAIL() << "expected a throw";
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("NeoHookean"), std::string::npos) << msg;
    EXPECT_NE(msg.find("mu = -2"), std::string::npos) << msg;
  }
  EXPECT_THROW((sc::HenckyStVK<double, 2>{1, -1.5}.validate()), std::invalid_argument);  // < -mu
  EXPECT_NO_THROW((sc::HenckyStVK<double, 2>{1, -0.5}.validate()));
  EXPECT_THROW((sc::WeaklyCompressibleFluid<double, 3>{1, 0}.validate()), std::invalid_argument);
}

TEST(FixedCorotated, InvertedStressPushesBackTowardRest) {
  // Smooth through inversion: P matches finite differences of psi also for det F < 0.
  const sc::FixedCorotated<double, 3> model{kMu, kLambda};
  std::mt19937 rng(15);
  for (int k = 0; k < 10; ++k) {
    const Eigen::Matrix3d F = random_rotation<3>(rng) *
                              Eigen::Vector3d(1.2, 0.9, -0.3).asDiagonal() *
                              random_rotation<3>(rng).transpose();
    Eigen::Matrix3d P_fd;
    for (int i = 0; i < 9; ++i) {
      Eigen::Matrix3d Fp = F, Fm = F;
      Fp(i) += kStep;
      Fm(i) -= kStep;
      P_fd(i) = (model.energy(Fp) - model.energy(Fm)) / (2 * kStep);
    }
    const Eigen::Matrix3d P = model.piola(F);
    EXPECT_LT((P - P_fd).norm(), kFdTol * P.norm());
    // Energy in terms of the signed singular values: mu sum (s - 1)^2 + lambda/2 (J - 1)^2.
    const double J = 1.2 * 0.9 * -0.3;
    const double psi = kMu * (0.04 + 0.01 + 1.69) + 0.5 * kLambda * (J - 1) * (J - 1);
    EXPECT_NEAR(model.energy(F), psi, 1e-12);
  }
}

TEST(CorotatedLinear, EnergyOfPrincipalStretch) {
  // F = R diag(s) R'^T: psi = mu sum (s - 1)^2 + lambda/2 (sum (s - 1))^2, differing from the
  // fixed corotated model only in the volume term.
  const sc::CorotatedLinear<double, 3> model{kMu, kLambda};
  std::mt19937 rng(16);
  const Eigen::Vector3d s(1.3, 0.8, 1.05);
  const Eigen::Matrix3d F =
      random_rotation<3>(rng) * s.asDiagonal() * random_rotation<3>(rng).transpose();
  const double tr = (s.array() - 1).sum();
  EXPECT_NEAR(model.energy(F), kMu * (s.array() - 1).square().sum() + 0.5 * kLambda * tr * tr,
              1e-12);
}

TEST(HenckyStVK, KirchhoffIsLinearInLogStrain) {
  // Uniaxial stretch a along x: eps = (log a, 0, 0), tau = diag(2 mu + lambda, lambda, lambda) log
  // a.
  const sc::HenckyStVK<double, 3> model{kMu, kLambda};
  const double a = 1.7;
  const Eigen::Matrix3d tau = model.kirchhoff(Eigen::Vector3d(a, 1, 1).asDiagonal());
  const Eigen::Vector3d expected =
      std::log(a) * Eigen::Vector3d(2 * kMu + kLambda, kLambda, kLambda);
  EXPECT_LT((tau - Eigen::Matrix3d(expected.asDiagonal())).norm(), 1e-14);
}

TEST(NeoHookean, UniaxialStretch) {
  // F = diag(a, 1, 1): P = diag(mu a + (lambda log a - mu)/a, lambda log a, lambda log a).
  const sc::NeoHookean<double, 3> model{kMu, kLambda};
  const double a = 1.4;
  const Eigen::Matrix3d P = model.piola(Eigen::Vector3d(a, 1, 1).asDiagonal());
  EXPECT_NEAR(P(0, 0), kMu * a + (kLambda * std::log(a) - kMu) / a, 1e-14);
  EXPECT_NEAR(P(1, 1), kLambda * std::log(a), 1e-14);
  EXPECT_NEAR(P(0, 1), 0, 1e-15);
  // Outside the model (J <= 0): infinite energy, finite stress.
  const Eigen::Matrix3d inverted = Eigen::Vector3d(1, 1, -0.5).asDiagonal();
  EXPECT_TRUE(std::isinf(model.energy(inverted)));
  EXPECT_TRUE(model.piola(inverted).allFinite());
}

TEST(WeaklyCompressibleFluid, EquationOfState) {
  const sc::WeaklyCompressibleFluid<double, 3> fluid{kBulk, 7.0};
  EXPECT_EQ(fluid.pressure(1.0), 0.0);
  EXPECT_EQ(fluid.energy_J(1.0), 0.0);
  // Tait: p(J) = K/gamma (J^-gamma - 1).
  EXPECT_NEAR(fluid.pressure(0.9), kBulk / 7.0 * (std::pow(0.9, -7.0) - 1), 1e-14);
  EXPECT_NEAR(fluid.kirchhoff_pressure(0.9), 0.9 * fluid.pressure(0.9), 1e-14);
  // Bulk modulus: -dp/dJ = K at J = 1.
  EXPECT_NEAR(fluid.pressure_derivative(1.0), -kBulk, 1e-14);
  // d psi / dJ = -p, by central differences (error ~h^2 psi''' ~ 1e-9).
  for (double J : {0.5, 0.8, 1.0, 1.3, 2.0}) {
    const double h = 1e-5;
    const double dpsi = (fluid.energy_J(J + h) - fluid.energy_J(J - h)) / (2 * h);
    EXPECT_NEAR(dpsi, -fluid.pressure(J), 1e-7 * (1 + std::abs(fluid.pressure(J)))) << "J = " << J;
  }
  // gamma = 1 (logarithmic energy) is the limit of gamma -> 1.
  const sc::WeaklyCompressibleFluid<double, 3> log_fluid{kBulk, 1.0};
  const sc::WeaklyCompressibleFluid<double, 3> near_log{kBulk, 1.0 + 1e-9};
  EXPECT_NEAR(log_fluid.energy_J(0.6), kBulk * ((0.6 - 1) - std::log(0.6)), 1e-14);
  EXPECT_NEAR(near_log.energy_J(0.6), log_fluid.energy_J(0.6), 1e-8);
  // Speed of sound: c^2 = dp/drho with rho = rho0 / J, so c(J)^2 / c(1)^2 = (dp/drho)(J) / (K / rho0),
  // by central differences of p in rho (error ~h^2 p''' ~ 1e-8 relative).
  for (double J : {0.5, 0.8, 0.83, 1.0, 1.3, 2.0}) {
    const double rho0 = 1000, rho = rho0 / J, h = 1e-3;
    const double dp_drho = (fluid.pressure(rho0 / (rho + h)) - fluid.pressure(rho0 / (rho - h))) / (2 * h);
    EXPECT_NEAR(fluid.sound_speed_ratio(J), std::sqrt(dp_drho / (kBulk / rho0)), 1e-6) << "J = " << J;
  }
  EXPECT_NEAR(fluid.sound_speed_ratio(0.83), 1.75, 0.005);  // the file comment's figure
  EXPECT_EQ(log_fluid.sound_speed_ratio(0.5), 1.0);          // gamma = 1: c does not depend on J
  // The matrix versions use J = det F: tau = -J p I.
  const Eigen::Matrix3d F = Eigen::Vector3d(0.9, 1.0, 0.95).asDiagonal();
  const double J = 0.9 * 0.95;
  EXPECT_LT((fluid.kirchhoff(F) + J * fluid.pressure(J) * Eigen::Matrix3d::Identity()).norm(),
            1e-13);
}

}  // namespace
