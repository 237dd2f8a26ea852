// Tests for constitutive/plasticity.h: after a projection that yields the state is on the yield
// surface; inside it nothing changes; the invariants each return map promises (Je Jp for snow,
// volume for von Mises and for the Drucker-Prager cone) hold.
#include <gtest/gtest.h>

#include "test_util.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <vector>

#include "slurry/constitutive/hencky_stvk.h"
#include "slurry/constitutive/plasticity.h"
#include "slurry/constitutive/svd.h"

namespace {

using slurry::test::kPi;
using slurry::test::random_rotation;

namespace sc = slurry::constitutive;

constexpr double kMu = 3.0;
constexpr double kLambda = 5.0;


template <int D>
Eigen::Matrix<double, D, 1> singular_values(const Eigen::Matrix<double, D, D>& F) {
  Eigen::Matrix<double, D, D> U, V;
  Eigen::Matrix<double, D, 1> s;
  sc::svd(F, U, s, V);
  return s;
}

/// Principal Kirchhoff stresses of the Hencky St. Venant-Kirchhoff model at Fe.
template <int D>
Eigen::Matrix<double, D, 1> principal_tau(const Eigen::Matrix<double, D, D>& Fe) {
  const Eigen::Matrix<double, D, 1> eps = singular_values<D>(Fe).array().log().matrix();
  return sc::HenckyStVK<double, D>{kMu, kLambda}.principal_kirchhoff(eps);
}

template <int D>
Eigen::Matrix<double, D, D> with_singular_values(const Eigen::Matrix<double, D, 1>& s,
                                                 std::mt19937& rng) {
  return random_rotation<D>(rng) * s.asDiagonal() * random_rotation<D>(rng).transpose();
}

template <class C>
class PlasticityTest : public ::testing::Test {};
template <int D>
struct Dim {
  static constexpr int value = D;
};
using Dims = ::testing::Types<Dim<2>, Dim<3>>;
TYPED_TEST_SUITE(PlasticityTest, Dims);

// The projections are closed-form in the singular values, so their results are exact up to the
// round-off of one SVD, a log and an exp (~1e-15 relative). 1e-9 relative is far below any
// error of the projection itself (a wrong step size misses the surface by O(1) relative).
constexpr double kTol = 1e-9;

// --- snow ------------------------------------------------------------------------------------

TYPED_TEST(PlasticityTest, SnowClampsIntoWindowKeepingJeJp) {
  constexpr int D = TypeParam::value;
  const sc::SnowPlasticity<double> snow;  // theta_c = 2.5e-2, theta_s = 7.5e-3
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(0.9, 1.1);
  int yielded = 0;
  for (int k = 0; k < 200; ++k) {
    Eigen::Matrix<double, D, 1> s;
    for (int i = 0; i < D; ++i) s(i) = u(rng);
    Eigen::Matrix<double, D, D> Fe = with_singular_values<D>(s, rng);
    const Eigen::Matrix<double, D, D> before = Fe;
    const double Jp0 = 0.8 + 0.4 * k / 200.0;
    double Jp = Jp0;
    const bool y = snow.project(Fe, Jp);
    EXPECT_EQ(y, snow.yield_function(s) > 0);
    const Eigen::Matrix<double, D, 1> s_new = singular_values<D>(Fe);
    if (y) {
      ++yielded;
      EXPECT_NEAR(snow.yield_function(s_new), 0, kTol);  // on the boundary of the window
    } else {
      EXPECT_EQ(Fe, before);  // untouched, bit for bit
    }
    EXPECT_LE(s_new.maxCoeff(), 1 + snow.critical_stretch + kTol);
    EXPECT_GE(s_new.minCoeff(), 1 - snow.critical_compression - kTol);
    EXPECT_NEAR(Fe.determinant() * Jp, before.determinant() * Jp0, kTol);
  }
  EXPECT_GT(yielded, 100);  // the sampling does exercise the projection
}

TEST(SnowPlasticity, ClampKeepsRotationsAndHardeningFactor) {
  const sc::SnowPlasticity<double> snow;
  std::mt19937 rng(22);
  const Eigen::Matrix3d U = random_rotation<3>(rng), V = random_rotation<3>(rng);
  Eigen::Matrix3d Fe = U * Eigen::Vector3d(1.2, 1.0, 0.5).asDiagonal() * V.transpose();
  double Jp = 1;
  EXPECT_TRUE(snow.project(Fe, Jp));
  const Eigen::Vector3d clamped(1.0075, 1.0, 0.975);
  EXPECT_LT((Fe - U * clamped.asDiagonal() * V.transpose()).norm(), 1e-14);
  EXPECT_NEAR(Jp, 1.2 * 0.5 / (1.0075 * 0.975), 1e-14);
  // Hardening exp(xi (1 - Jp)): 1 at rest, e at Jp = 0.9, capped at max_hardening.
  EXPECT_DOUBLE_EQ(snow.hardening_factor(1.0), 1.0);
  EXPECT_NEAR(snow.hardening_factor(0.9), std::exp(1.0), 1e-14);
  EXPECT_NEAR(snow.hardening_factor(0.0), snow.max_hardening, 1e-12);
  EXPECT_NEAR(snow.hardening_factor(1.5), std::exp(-5.0), 1e-16);
}

// The window test of SnowPlasticity::project() must never skip a particle the SVD path would
// clamp: for singular values spread over and around the window (including within 1e-6 of its
// edges, inside and out), in float and double, 2D and 3D, project() and project_by_svd() leave
// bitwise the same Fe and Jp and return the same answer; and the test does skip most particles
// well inside the window (else it saves nothing).
template <class T, int D>
void window_test_agrees_with_svd(unsigned seed) {
  const sc::SnowPlasticity<T> snow;
  std::mt19937 rng(seed);
  const double lo = 1 - 2.5e-2, hi = 1 + 7.5e-3;
  std::uniform_real_distribution<double> spread(lo - 0.01, hi + 0.01), pick(0, 1), edge(-1e-6, 1e-6);
  int skipped = 0, skipped_deep = 0, deep = 0, yielded = 0;
  std::vector<Eigen::Matrix<T, D, D>> samples;
  std::vector<char> svd_yields, is_deep;
  for (int k = 0; k < 20000; ++k) {
    Eigen::Matrix<double, D, 1> sigma;
    const bool inside = k % 2 == 0;
    for (int d = 0; d < D; ++d) {
      const double u = pick(rng);
      if (inside)
        sigma[d] = lo + 0.1 * (hi - lo) + 0.8 * (hi - lo) * u;  // deep inside
      else
        sigma[d] = u < 0.3 ? lo + edge(rng) : u < 0.6 ? hi + edge(rng) : spread(rng);
    }
    const Eigen::Matrix<T, D, D> F0 =
        (random_rotation<D>(rng) * sigma.asDiagonal() * random_rotation<D>(rng).transpose()).template cast<T>();
    Eigen::Matrix<T, D, D> Fa = F0, Fb = F0;
    T Ja = T(0.9), Jb = T(0.9);
    const bool ya = snow.project(Fa, Ja), yb = snow.project_by_svd(Fb, Jb);
    ASSERT_EQ(ya, yb) << "sample " << k;
    ASSERT_EQ(Ja, Jb) << "sample " << k;
    for (int i = 0; i < D * D; ++i) ASSERT_EQ(Fa.data()[i], Fb.data()[i]) << "sample " << k;
    const bool skip = snow.inside_window(F0);
    skipped += skip;
    if (inside) ++deep, skipped_deep += skip;
    yielded += yb;
    samples.push_back(F0), svd_yields.push_back(yb), is_deep.push_back(inside);
  }
  // The 16-lane form, inside_windows(), through an index list (reversed, the last batch partial):
  // a lane it clears must be one the SVD path leaves alone, and it must clear most deep ones.
  std::vector<std::uint32_t> ids(samples.size() - 3);
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = std::uint32_t(ids.size() - 1 - i);
  int lanes_deep = 0, ids_deep = 0;
  for (std::size_t i = 0; i < ids.size(); i += 16) {
    const int n = int(std::min<std::size_t>(16, ids.size() - i));
    bool in[16];
    snow.template inside_windows<D, 16>(samples.data(), ids.data() + i, n, in);
    for (int k = 0; k < n; ++k) {
      const auto q = ids[i + std::size_t(k)];
      if (in[k]) {
        ASSERT_FALSE(svd_yields[q]) << "sample " << q;
      }
      lanes_deep += in[k] && is_deep[q];
      ids_deep += is_deep[q];
    }
  }
  EXPECT_GT(lanes_deep, ids_deep * 9 / 10);
  EXPECT_GT(yielded, 3000);                // the edges and the spread do yield
  EXPECT_GT(skipped_deep, deep * 9 / 10);  // the test skips the SVD for most particles inside
  std::printf("%s %dD: SVD skipped for %d of %d samples well inside the window\n", sizeof(T) == 4 ? "float" : "double",
              D, skipped_deep, deep);
  EXPECT_LT(skipped, 20000 - yielded + 1);
}

TEST(SnowPlasticity, WindowTestAgreesWithTheSvdPath) {
  window_test_agrees_with_svd<float, 2>(1);
  window_test_agrees_with_svd<float, 3>(2);
  window_test_agrees_with_svd<double, 2>(3);
  window_test_agrees_with_svd<double, 3>(4);
}

// --- Drucker-Prager -------------------------------------------------------------------------

TEST(DruckerPrager, AlphaFromFrictionAngle) {
  sc::DruckerPrager<double> dp;
  dp.friction_angle = 30;  // sin = 1/2: alpha = sqrt(2/3) * 1 / 2.5
  EXPECT_NEAR(dp.alpha(), std::sqrt(2.0 / 3.0) / 2.5, 1e-15);
  dp.friction_angle = 0;
  EXPECT_EQ(dp.alpha(), 0.0);
  EXPECT_THROW((sc::DruckerPrager<double>{90}.validate()), std::invalid_argument);
  EXPECT_NO_THROW((sc::DruckerPrager<double>{35}.validate()));
}

// A 2D run is the plane-strain slice of the 3D material: the 2D yield function of in-plane
// principal stresses equals the 3D one with the out-of-plane stress at the in-plane mean (its
// value in isochoric plastic flow without out-of-plane strain), and at yield the in-plane
// Mohr-Coulomb angle is asin(3 alpha_3 / sqrt 2), 43.9 degrees for phi = 30.
TEST(DruckerPrager, TwoDimensionalConeIsThePlaneStrainSliceOfTheThreeDimensionalOne) {
  sc::DruckerPrager<double> dp;
  std::mt19937 rng(31);
  std::uniform_real_distribution<double> u(-3.0, 1.0);
  for (double phi : {10.0, 30.0, 40.0}) {
    dp.friction_angle = phi;
    EXPECT_NEAR(dp.alpha<2>(), 1.5 * dp.alpha<3>(), 1e-15);
    for (int i = 0; i < 200; ++i) {
      const double t1 = u(rng), t2 = u(rng);
      const double y2 = dp.yield_function<2>(Eigen::Vector2d(t1, t2));
      const double y3 = dp.yield_function<3>(Eigen::Vector3d(t1, t2, 0.5 * (t1 + t2)));
      EXPECT_NEAR(y2, y3, 1e-12) << phi << " " << t1 << " " << t2;
    }
  }
  dp.friction_angle = 30;
  // On the 2D cone under compression p: |t1 - t2| = sin(phi_in_plane) * (-(t1 + t2)).
  const double p = 1.0, k = 3 * dp.alpha<3>() / std::sqrt(2.0);
  const double t1 = -p + k * p, t2 = -p - k * p;
  EXPECT_NEAR(dp.yield_function<2>(Eigen::Vector2d(t1, t2)), 0.0, 1e-12);
  EXPECT_NEAR(std::asin(k) * 180 / 3.14159265358979323846, 43.85, 0.01);
}

TYPED_TEST(PlasticityTest, DruckerPragerTensionReturnsToTip) {
  constexpr int D = TypeParam::value;
  const sc::DruckerPrager<double> dp;
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> u(0.98, 1.1);
  for (int k = 0; k < 100; ++k) {
    Eigen::Matrix<double, D, 1> s;
    for (int i = 0; i < D; ++i) s(i) = u(rng);
    if (s.prod() <= 1) continue;  // tr(log s) > 0: net tension
    Eigen::Matrix<double, D, D> U = random_rotation<D>(rng), V = random_rotation<D>(rng);
    Eigen::Matrix<double, D, D> Fe = U * s.asDiagonal() * V.transpose();
    double state = 0.25;
    EXPECT_TRUE(dp.project(Fe, state, kMu, kLambda));
    // Fe is the rotation U V^T: singular values 1, stress zero (the apex of the cone).
    EXPECT_LT((Fe - U * V.transpose()).norm(), kTol);
    EXPECT_LT((Fe.transpose() * Fe - Eigen::Matrix<double, D, D>::Identity()).norm(), kTol);
    EXPECT_NEAR(state, 0.25 + s.array().log().matrix().norm(), kTol);
  }
}

TYPED_TEST(PlasticityTest, DruckerPragerCompressionWithShearLandsOnCone) {
  constexpr int D = TypeParam::value;
  const sc::DruckerPrager<double> dp;
  std::mt19937 rng(24);
  std::uniform_real_distribution<double> u(-0.15, 0.15);
  int on_cone = 0;
  for (int k = 0; k < 300; ++k) {
    Eigen::Matrix<double, D, 1> eps;
    for (int i = 0; i < D; ++i) eps(i) = u(rng);
    eps.array() -= 0.03;  // bias to compression
    if (eps.sum() >= 0) continue;
    const Eigen::Matrix<double, D, 1> s = eps.array().exp().matrix();
    Eigen::Matrix<double, D, D> Fe = with_singular_values<D>(s, rng);
    const Eigen::Matrix<double, D, D> before = Fe;
    const Eigen::Matrix<double, D, 1> tau0 = principal_tau<D>(Fe);
    const double scale = tau0.norm();
    double state = 0;
    const bool yielded = dp.project(Fe, state, kMu, kLambda);
    EXPECT_EQ(yielded, dp.yield_function(tau0) > 0);
    if (!yielded) {
      EXPECT_EQ(Fe, before);
      EXPECT_EQ(state, 0);
      continue;
    }
    ++on_cone;
    const Eigen::Matrix<double, D, 1> tau = principal_tau<D>(Fe);
    EXPECT_NEAR(dp.yield_function(tau), 0, kTol * scale);       // on the cone
    EXPECT_NEAR(Fe.determinant(), before.determinant(), kTol);  // the cone return keeps tr(eps)
    // delta_gamma = y(tau0) / (2 mu) (the return map in strain units).
    EXPECT_NEAR(state, dp.yield_function(tau0) / (2 * kMu), kTol);
    // Projecting again changes nothing beyond round-off.
    const Eigen::Matrix<double, D, D> once = Fe;
    dp.project(Fe, state, kMu, kLambda);
    EXPECT_LT((Fe - once).norm(), kTol);
  }
  EXPECT_GT(on_cone, 50);
}

TYPED_TEST(PlasticityTest, DruckerPragerInsideIsUnchanged) {
  constexpr int D = TypeParam::value;
  const sc::DruckerPrager<double> dp;
  std::mt19937 rng(25);
  // Pure compression (no shear) is always inside the cone.
  Eigen::Matrix<double, D, 1> s;
  s.setConstant(0.95);
  Eigen::Matrix<double, D, D> Fe = with_singular_values<D>(s, rng);
  const Eigen::Matrix<double, D, D> before = Fe;
  double state = 0;
  EXPECT_FALSE(dp.project(Fe, state, kMu, kLambda));
  EXPECT_EQ(Fe, before);
  EXPECT_EQ(state, 0);
}

TEST(DruckerPrager, InvertedFeIsUninverted) {
  const sc::DruckerPrager<double> dp;
  Eigen::Matrix3d Fe = Eigen::Vector3d(1.0, 0.9, -0.2).asDiagonal();
  double state = 0;
  EXPECT_TRUE(dp.project(Fe, state, kMu, kLambda));
  EXPECT_TRUE(Fe.allFinite());
  EXPECT_GT(Fe.determinant(), 0);
  EXPECT_LE(dp.yield_function(principal_tau<3>(Fe)), kTol * kMu);
}

// The projection never creates elastic energy: psi(Fe) after <= psi(Fe) before, for tension
// (to the tip, psi = 0), compression with shear (onto the cone at the same tr(eps), only the
// deviatoric part shrinks) and states inside (unchanged). Energy created at the return mapping
// is what an exploding granular scene would show.
TYPED_TEST(PlasticityTest, DruckerPragerNeverCreatesElasticEnergy) {
  constexpr int D = TypeParam::value;
  const sc::DruckerPrager<double> dp;
  const sc::HenckyStVK<double, D> model{kMu, kLambda};
  std::mt19937 rng(26);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  int yielded = 0;
  for (int k = 0; k < 2000; ++k) {
    Eigen::Matrix<double, D, 1> eps;
    for (int i = 0; i < D; ++i) eps(i) = u(rng);
    Eigen::Matrix<double, D, D> Fe = with_singular_values<D>(eps.array().exp().matrix(), rng);
    const double before = model.energy(Fe);
    double state = 0;
    yielded += dp.project(Fe, state, kMu, kLambda);
    EXPECT_LE(model.energy(Fe), before * (1 + kTol) + kTol) << "eps = " << eps.transpose();
    EXPECT_GE(state, 0);
  }
  EXPECT_GT(yielded, 500);
}

// Sand at rest in float: Fe is the identity to a few ulps. The projection must leave it there
// (finite, within float round-off of F, no plastic strain beyond round-off). Before the 3x3 SVD
// fix (svd.h, the leftover trace of F^T F - qI) some of these came back NaN, and the 3D sand
// example exploded at step 92.
TEST(DruckerPrager, FloatFeAtRestStaysAtRest3D) {
  const sc::DruckerPrager<float> dp;
  std::mt19937 rng(27);
  int bad = 0;
  for (int n = 0; n < 200000; ++n) {
    Eigen::Matrix3f Fe = slurry::test::near_identity_by_ulps<float>(rng, 1.0f);
    const Eigen::Matrix3f before = Fe;
    float state = 0;
    dp.project(Fe, state, float(kMu), float(kLambda));
    if (!Fe.allFinite() || (Fe - before).norm() > 1e-5f || !(state < 1e-5f)) ++bad;
  }
  EXPECT_EQ(bad, 0);
}

// project_with_stress (the MPM step's P2G for sand) must project exactly as project() does, and
// its stress must be the Hencky Kirchhoff stress of the projected Fe: the same as factoring that
// Fe again (HenckyStVK::kirchhoff), to round-off. Covers the three branches (inside, onto the
// cone, to the tip) and a floored singular value.
TYPED_TEST(PlasticityTest, DruckerPragerStressFromTheProjectionsSvd) {
  constexpr int D = TypeParam::value;
  using M = Eigen::Matrix<double, D, D>;
  const sc::DruckerPrager<double> dp;
  const sc::HenckyStVK<double, D> model{kMu, kLambda};
  std::mt19937 rng(28);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  int inside = 0, cone = 0, tip = 0;
  for (int k = 0; k < 3000; ++k) {
    Eigen::Matrix<double, D, 1> eps;
    for (int i = 0; i < D; ++i) eps(i) = u(rng);
    if (k % 100 == 0) eps(D - 1) = std::log(1e-6);  // below min_singular_value: floored
    if (k % 7 == 0) eps.array() = eps.sum() / D - 0.01;  // pure compression: inside
    const M F0 = with_singular_values<D>(eps.array().exp().matrix(), rng);
    M Fa = F0, Fb = F0, tau;
    double sa = 0.5, sb = 0.5;
    const bool ya = dp.project(Fa, sa, kMu, kLambda);
    const bool yb = dp.project_with_stress(Fb, sb, kMu, kLambda, tau);
    ASSERT_EQ(ya, yb);
    ASSERT_EQ(Fa, Fb);  // bitwise: the same projection
    ASSERT_EQ(sa, sb);
    const M expected = model.kirchhoff(Fb);
    EXPECT_LT((tau - expected).norm(), 1e-11 * (1 + expected.norm())) << "eps = " << eps.transpose();
    EXPECT_LT((tau - tau.transpose()).norm(), 1e-12 * (1 + tau.norm()));
    if (!ya) ++inside;
    else if (tau.norm() == 0) ++tip;
    else ++cone;
  }
  EXPECT_GT(inside, 300);
  EXPECT_GT(cone, 300);
  EXPECT_GT(tip, 300);
}

// --- von Mises -------------------------------------------------------------------------------

TYPED_TEST(PlasticityTest, VonMisesReturnsToSurfaceAtConstantVolume) {
  constexpr int D = TypeParam::value;
  const sc::VonMises<double> vm{0.5};  // tau_y
  std::mt19937 rng(26);
  std::uniform_real_distribution<double> u(-0.2, 0.2);
  int yielded_count = 0;
  for (int k = 0; k < 300; ++k) {
    Eigen::Matrix<double, D, 1> eps;
    for (int i = 0; i < D; ++i) eps(i) = u(rng);
    Eigen::Matrix<double, D, D> Fe = with_singular_values<D>(eps.array().exp().matrix(), rng);
    const Eigen::Matrix<double, D, D> before = Fe;
    const Eigen::Matrix<double, D, 1> tau0 = principal_tau<D>(Fe);
    double state = 0;
    const bool yielded = vm.project(Fe, state, kMu);
    EXPECT_EQ(yielded, vm.yield_function(tau0) > 0);
    if (!yielded) {
      EXPECT_EQ(Fe, before);
      continue;
    }
    ++yielded_count;
    EXPECT_NEAR(vm.yield_function(principal_tau<D>(Fe)), 0, kTol * vm.yield_stress);
    EXPECT_NEAR(Fe.determinant(), before.determinant(), kTol);
    // Equivalent plastic strain sqrt(2/3) delta_gamma, delta_gamma = y(tau0) / (2 mu).
    EXPECT_NEAR(state, std::sqrt(2.0 / 3.0) * vm.yield_function(tau0) / (2 * kMu), kTol);
  }
  EXPECT_GT(yielded_count, 50);
}

TEST(VonMises, PureShearAnalytic) {
  // Fe = diag(e^a, e^-a, 1): eps^ = (a, -a, 0), ||dev tau|| = 2 mu a sqrt(2). On return,
  // ||dev tau|| = sqrt(2/3) tau_y, so the remaining shear strain is a' = tau_y / (2 sqrt(3) mu).
  const double tau_y = 0.6, a = 0.2;
  const sc::VonMises<double> vm{tau_y};
  Eigen::Matrix3d Fe = Eigen::Vector3d(std::exp(a), std::exp(-a), 1).asDiagonal();
  double state = 0;
  EXPECT_TRUE(vm.project(Fe, state, kMu));
  const double a_new = tau_y / (2 * std::sqrt(3.0) * kMu);
  EXPECT_NEAR(Fe(0, 0), std::exp(a_new), 1e-14);
  EXPECT_NEAR(Fe(1, 1), std::exp(-a_new), 1e-14);
  EXPECT_NEAR(Fe(2, 2), 1, 1e-14);
  EXPECT_NEAR(state, std::sqrt(2.0 / 3.0) * std::sqrt(2.0) * (a - a_new), 1e-14);
}

TEST(Plasticity, FloatInstantiation) {
  // The engine also runs in float; the same projections must compile and land on the surface
  // to float precision (1e-4 relative: a few float eps amplified by log/exp of O(0.1) strains).
  const sc::DruckerPrager<float> dp;
  Eigen::Matrix3f Fe = Eigen::Vector3f(0.8f, 1.15f, 0.97f).asDiagonal();  // shear beyond the cone
  float state = 0;
  EXPECT_TRUE(dp.project(Fe, state, float(kMu), float(kLambda)));
  const Eigen::Vector3d tau = principal_tau<3>(Fe.cast<double>());
  EXPECT_NEAR(sc::DruckerPrager<double>{}.yield_function(tau), 0, 1e-4 * tau.norm());
  const sc::VonMises<float> vm{0.5f};
  Eigen::Matrix2f G = Eigen::Vector2f(1.2f, 0.8f).asDiagonal();
  EXPECT_TRUE(vm.project(G, state, float(kMu)));
  const sc::SnowPlasticity<float> snow;
  float Jp = 1;
  EXPECT_TRUE(snow.project(G, Jp));
}

// The batched Drucker-Prager projection (project_with_stress over SIMD lanes, the 3D P2G's sand
// path) against the scalar one, lane by lane, on the scalar test's inputs: the same branch in
// every lane, Fe, state and tau to round-off (relative 1e-11 in double; 2e-5 in float, where
// the logs and exps of the Hencky strain each add an ulp or so), Fe bitwise unchanged where
// nothing yielded, and each lane's bits independent of its position and neighbours (the batch
// reversed gives the same bits). Lanes that the eigenvectors of Fe Fe^T may not serve (det Fe
// < 0, sigma_min^2 < kLeftEigenRatio sigma_max^2, a floored sigma) must carry exactly the bits
// of the full-SVD path, project_with_stress_svd, run on the same batch.
template <class T>
void check_drucker_prager_lanes(double tol) {
  constexpr int W = sc::lanes::kWidth<T>;
  using M = Eigen::Matrix<T, 3, 3>;
  const sc::DruckerPrager<T> dp;
  std::mt19937 rng(28);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::uniform_real_distribution<double> st(0, 1);
  int counts[3] = {0, 0, 0};  // inside, cone, tip
  int svd_lanes = 0;
  for (int batch = 0; batch < 3000 / W; ++batch) {
    sc::lanes::Mat3<T, W> F, F_rev, tau, tau_rev;
    sc::lanes::Lane<T, W> state, state_rev;
    std::vector<M> F0(W);
    bool svd_lane[W];
    for (int l = 0; l < W; ++l) {
      const int k = batch * W + l;
      Eigen::Vector3d eps;
      for (int i = 0; i < 3; ++i) eps(i) = u(rng);
      if (k % 100 == 0) eps(2) = std::log(1e-6);           // floored
      if (k % 100 == 50) eps(1) = std::log(0.01);          // sigma_min / sigma_max ~ 1e-2
      if (k % 7 == 0) eps.array() = eps.sum() / 3 - 0.01;  // pure compression: inside
      Eigen::Vector3d sv = eps.array().exp().matrix();
      svd_lane[l] = sv.minCoeff() < 2 * double(dp.min_singular_value) ||
                    sv.minCoeff() * sv.minCoeff() < double(sc::DruckerPrager<T>::kLeftEigenRatio) * sv.maxCoeff() * sv.maxCoeff();
      if (k % 100 == 30 && k % 7 != 0) {  // inverted (not the isotropic case: which axis gets
                                           // the sign, and so the floor, is arbitrary there)
        sv(2) = -sv(2);
        svd_lane[l] = true;
      }
      F0[std::size_t(l)] = with_singular_values<3>(sv, rng).template cast<T>();
      F.put(l, F0[std::size_t(l)]);
      F_rev.put(W - 1 - l, F0[std::size_t(l)]);
      state[l] = state_rev[W - 1 - l] = T(st(rng));
    }
    const sc::lanes::Lane<T, W> state0 = state;
    sc::lanes::Mat3<T, W> F_svd = F, tau_svd;
    sc::lanes::Lane<T, W> state_svd = state;
    const auto yielded_svd = dp.project_with_stress_svd(F_svd, state_svd, T(kMu), T(kLambda), tau_svd);
    const auto yielded = dp.project_with_stress(F, state, T(kMu), T(kLambda), tau);
    const auto yielded_rev = dp.project_with_stress(F_rev, state_rev, T(kMu), T(kLambda), tau_rev);
    for (int l = 0; l < W; ++l) {
      M Fs = F0[std::size_t(l)], tau_s;
      T ss = state0[l];
      const bool ys = dp.project_with_stress(Fs, ss, T(kMu), T(kLambda), tau_s);
      const bool yl = yielded.bits[l] != T(0);
      ASSERT_EQ(yl, ys) << "lane " << l << " of batch " << batch << "\nF =\n" << F0[std::size_t(l)];
      const M Fl = F.get(l), taul = tau.get(l);
      if (!yl) {
        EXPECT_EQ(Fl, F0[std::size_t(l)]) << "unchanged where nothing yielded";
      }
      EXPECT_LT(double((Fl - Fs).norm()), tol * double(Fs.norm()));
      EXPECT_NEAR(double(state[l]), double(ss), tol * (1 + double(ss)));
      EXPECT_LT(double((taul - tau_s).norm()), tol * kMu * (1 + double(tau_s.norm())));
      EXPECT_EQ(taul, taul.transpose());
      // Independent of the lane it sits in.
      EXPECT_EQ(Fl, F_rev.get(W - 1 - l));
      EXPECT_EQ(taul, tau_rev.get(W - 1 - l));
      EXPECT_EQ(state[l], state_rev[W - 1 - l]);
      EXPECT_EQ(yielded.bits[l] != T(0), yielded_rev.bits[W - 1 - l] != T(0));
      if (svd_lane[l]) {
        ++svd_lanes;
        EXPECT_EQ(Fl, F_svd.get(l)) << "lane " << l << " of batch " << batch << ": not the SVD path's bits";
        EXPECT_EQ(taul, tau_svd.get(l));
        EXPECT_EQ(state[l], state_svd[l]);
        EXPECT_EQ(yl, yielded_svd.bits[l] != T(0));
      }
      ++counts[!ys ? 0 : (tau_s.norm() == 0 ? 2 : 1)];
    }
    if (::testing::Test::HasFailure()) return;
  }
  EXPECT_GT(counts[0], 300);
  EXPECT_GT(counts[1], 300);
  EXPECT_GT(counts[2], 300);
  EXPECT_GT(svd_lanes, 60);  // about 3 in 100
}
TEST(DruckerPragerLanes, AgreesWithTheScalarProjectionDouble) { check_drucker_prager_lanes<double>(1e-11); }
TEST(DruckerPragerLanes, AgreesWithTheScalarProjectionFloat) { check_drucker_prager_lanes<float>(2e-5); }

}  // namespace
