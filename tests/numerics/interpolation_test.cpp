// Tests of slurry/engine/numerics/interpolation.h: polynomial reproduction, partition of unity,
// inside tests, least squares and moving least squares.
#include "slurry/engine/numerics/interpolation.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <iostream>
#include <random>
#include <vector>

namespace sn = slurry::numerics;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

namespace {

// Round-off budget for evaluating a handful of O(1) products and sums in double precision:
// each operation contributes <= 1.1e-16 relative, and a few dozen of them stay below 1e-14.
constexpr double kRoundOff = 1e-13;

double horner(const VectorXd& c, double x) {
  double p = 0;
  for (Eigen::Index k = c.size() - 1; k >= 0; --k) p = p * x + c[k];
  return p;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Multilinear
// ---------------------------------------------------------------------------------------------

TEST(Multilinear, LinearReproducesAffineFunction) {
  // f(x) = 3 - 2x on the cell [0.5, 0.75]: corner values and any s give f exactly.
  const auto f = [](double x) { return 3.0 - 2.0 * x; };
  for (double s : {0.0, 0.1, 0.5, 0.9, 1.0}) {
    const double x = 0.5 + 0.25 * s;
    EXPECT_NEAR(sn::linear(f(0.5), f(0.75), s), f(x), kRoundOff);
  }
}

TEST(Multilinear, BilinearReproducesBilinearFunctions) {
  // f = a + b x + c y + d x y is in the span of the bilinear shape functions.
  const auto f = [](double x, double y) { return 1.5 + 2.0 * x - 0.7 * y + 0.3 * x * y; };
  const double x0 = -1.0, y0 = 2.0, h = 0.5;
  std::array<double, 4> c{};
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 2; ++i) c[i + 2 * j] = f(x0 + h * i, y0 + h * j);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  for (int k = 0; k < 50; ++k) {
    const double s = u01(rng), t = u01(rng);
    EXPECT_NEAR(sn::bilinear(c, s, t), f(x0 + h * s, y0 + h * t), kRoundOff);
    const auto w = sn::bilinear_weights(s, t);
    EXPECT_NEAR(w[0] + w[1] + w[2] + w[3], 1.0, 1e-15);  // 4 terms, each exact to 1 ulp
  }
}

TEST(Multilinear, TrilinearReproducesTrilinearFunctionsAndVectors) {
  const auto f = [](const Vector3d& x) {
    return 0.5 - x.x() + 2.0 * x.y() + 0.25 * x.z() + 0.1 * x.x() * x.y() * x.z();
  };
  const Vector3d x0(0.2, -0.3, 1.0);
  const double h = 0.125;
  std::array<double, 8> c{};
  std::array<Vector3d, 8> cv{};  // vector-valued corners: an affine vector field
  const auto g = [](const Vector3d& x) { return Vector3d(x.y() - 1.0, 2.0 * x.z(), x.x() + 4.0); };
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 2; ++i) {
        const Vector3d x = x0 + h * Vector3d(i, j, k);
        c[i + 2 * j + 4 * k] = f(x);
        cv[i + 2 * j + 4 * k] = g(x);
      }
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  for (int n = 0; n < 50; ++n) {
    const Vector3d s(u01(rng), u01(rng), u01(rng));
    const Vector3d x = x0 + h * s;
    EXPECT_NEAR(sn::trilinear(c, s.x(), s.y(), s.z()), f(x), kRoundOff);
    EXPECT_LT((sn::trilinear(cv, s.x(), s.y(), s.z()) - g(x)).norm(), kRoundOff);
    const auto w = sn::trilinear_weights(s.x(), s.y(), s.z());
    double sum = 0;
    for (double wi : w) {
      EXPECT_GE(wi, 0.0);
      sum += wi;
    }
    EXPECT_NEAR(sum, 1.0, 1e-15);
  }
  // At a corner the weights select that corner.
  const auto w = sn::trilinear_weights(1.0, 0.0, 1.0);
  for (int corner = 0; corner < 8; ++corner) EXPECT_EQ(w[corner], corner == 5 ? 1.0 : 0.0);
}

// ---------------------------------------------------------------------------------------------
// Barycentric coordinates
// ---------------------------------------------------------------------------------------------

TEST(Barycentric, Triangle2DReproducesLinearFunctions) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const auto lin = [](const Vector2d& p) { return 0.3 + 1.7 * p.x() - 2.2 * p.y(); };
  for (int trial = 0; trial < 100; ++trial) {
    const Vector2d a(u(rng), u(rng)), b(u(rng), u(rng)), c(u(rng), u(rng));
    const double area2 = std::abs((b - a).x() * (c - a).y() - (b - a).y() * (c - a).x());
    if (area2 < 0.1) continue;         // keep the triangles well shaped so round-off stays ~1e-15
    const Vector2d p(u(rng), u(rng));  // inside or outside: coordinates are signed
    const Eigen::Vector3d w = sn::barycentric(p, a, b, c);
    EXPECT_NEAR(w.sum(), 1.0, kRoundOff);
    EXPECT_LT((w[0] * a + w[1] * b + w[2] * c - p).norm(), kRoundOff * 10);
    EXPECT_NEAR(w[0] * lin(a) + w[1] * lin(b) + w[2] * lin(c), lin(p), kRoundOff * 10);
    // Orientation does not matter: swapping b and c swaps their coordinates.
    const Eigen::Vector3d w_swapped = sn::barycentric(p, a, c, b);
    EXPECT_NEAR(w_swapped[1], w[2], kRoundOff);
    EXPECT_NEAR(w_swapped[2], w[1], kRoundOff);
  }
}

TEST(Barycentric, Triangle3DUsesTheProjectionOntoThePlane) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vector3d a(0.1, 0.2, 0.3), b(1.3, -0.2, 0.5), c(0.4, 1.1, -0.6);
  const Vector3d n = (b - a).cross(c - a).normalized();
  for (int trial = 0; trial < 50; ++trial) {
    Vector3d lambda(u(rng), u(rng), 0.0);
    lambda[2] = 1.0 - lambda[0] - lambda[1];
    const Vector3d q = lambda[0] * a + lambda[1] * b + lambda[2] * c;  // in the plane
    const Vector3d p = q + 3.0 * u(rng) * n;                           // off the plane
    const Vector3d w = sn::barycentric(p, a, b, c);
    EXPECT_LT((w - lambda).norm(), kRoundOff);
    EXPECT_NEAR(w.sum(), 1.0, kRoundOff);
  }
}

TEST(Barycentric, TetrahedronReproducesLinearFunctions) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Vector3d a(0, 0, 0), b(1.2, 0.1, -0.1), c(0.2, 0.9, 0.3), d(-0.1, 0.3, 1.1);
  const auto lin = [](const Vector3d& p) { return 2.0 - p.x() + 0.5 * p.y() + 3.0 * p.z(); };
  for (int trial = 0; trial < 50; ++trial) {
    const Vector3d p(u(rng), u(rng), u(rng));
    const Eigen::Vector4d w = sn::barycentric(p, a, b, c, d);
    EXPECT_NEAR(w.sum(), 1.0, kRoundOff);
    EXPECT_LT((w[0] * a + w[1] * b + w[2] * c + w[3] * d - p).norm(), kRoundOff);
    EXPECT_NEAR(w[0] * lin(a) + w[1] * lin(b) + w[2] * lin(c) + w[3] * lin(d), lin(p),
                kRoundOff * 10);
  }
  EXPECT_LT((sn::barycentric(c, a, b, c, d) - Eigen::Vector4d(0, 0, 1, 0)).norm(), kRoundOff);
}

TEST(Barycentric, InsideTestWithTolerance) {
  const Vector2d a(0, 0), b(1, 0), c(0, 1);
  const auto in2 = [&](const Vector2d& p, double tol) {
    return sn::is_inside(sn::barycentric(p, a, b, c), tol);
  };
  EXPECT_TRUE(in2(Vector2d(0.25, 0.25), 0.0));   // interior
  EXPECT_TRUE(in2(Vector2d(0.5, 0.5), 0.0));     // on the hypotenuse (coordinate exactly 0)
  EXPECT_TRUE(in2(Vector2d(1.0, 0.0), 0.0));     // vertex
  EXPECT_TRUE(in2(Vector2d(0.5, 0.0), 0.0));     // on an edge
  EXPECT_FALSE(in2(Vector2d(1.0, 1.0), 0.0));    // outside
  EXPECT_FALSE(in2(Vector2d(-0.1, 0.5), 0.0));   // outside, across another edge
  EXPECT_FALSE(in2(Vector2d(0.5, -1e-3), 0.0));  // just outside ...
  EXPECT_TRUE(in2(Vector2d(0.5, -1e-3), 1e-2));  // ... but within the tolerance
  EXPECT_FALSE(in2(Vector2d(0.5, -1e-1), 1e-2));

  const Vector3d ta(0, 0, 0), tb(1, 0, 0), tc(0, 1, 0), td(0, 0, 1);
  const auto in3 = [&](const Vector3d& p, double tol) {
    return sn::is_inside(sn::barycentric(p, ta, tb, tc, td), tol);
  };
  // Points on the slanted face get coordinates of order 1e-17 of either sign: tolerance 1e-12.
  EXPECT_TRUE(in3(Vector3d(0.25, 0.25, 0.25), 0.0));
  EXPECT_TRUE(in3(Vector3d(1.0 / 3, 1.0 / 3, 1.0 / 3), 1e-12));
  EXPECT_TRUE(in3(Vector3d(0.0, 0.0, 1.0), 1e-12));
  EXPECT_FALSE(in3(Vector3d(0.5, 0.5, 0.5), 1e-12));
  EXPECT_FALSE(in3(Vector3d(0.2, 0.2, -0.01), 1e-3));
  EXPECT_TRUE(in3(Vector3d(0.2, 0.2, -0.01), 0.1));
}

// ---------------------------------------------------------------------------------------------
// Lagrange and Newton
// ---------------------------------------------------------------------------------------------

TEST(PolynomialInterpolation, ReproducesDegreeNThroughNPlusOnePoints) {
  const VectorXd coeffs = (VectorXd(6) << 0.5, -1.0, 2.0, 0.25, -0.75, 0.125).finished();
  const int n = 5;  // degree; n + 1 = 6 nodes
  VectorXd xs(n + 1), ys(n + 1);
  for (int i = 0; i <= n; ++i) {
    xs[i] = -1.0 + 3.0 * i / n;  // equispaced in [-1, 2]
    ys[i] = horner(coeffs, xs[i]);
  }
  const VectorXd newton = sn::newton_divided_differences(xs, ys);
  // |p| <= ~40 on [-1.5, 2.5]; the Lagrange products amplify round-off by the Lebesgue-like sum
  // of |l_i| (< 100 even slightly outside the nodes), so 1e-11 absolute is a safe round-off bound.
  double max_err_lagrange = 0, max_err_newton = 0;
  for (int k = 0; k <= 100; ++k) {
    const double x = -1.5 + 4.0 * k / 100;
    max_err_lagrange = std::max(max_err_lagrange,
                                std::abs(sn::lagrange_interpolate(xs, ys, x) - horner(coeffs, x)));
    max_err_newton =
        std::max(max_err_newton, std::abs(sn::newton_evaluate(xs, newton, x) - horner(coeffs, x)));
  }
  EXPECT_LT(max_err_lagrange, 1e-11);
  EXPECT_LT(max_err_newton, 1e-11);
  // Newton's leading coefficient is the leading coefficient of the polynomial.
  EXPECT_NEAR(newton[n], coeffs[n], 1e-12);

  // Degree n + 1 is not reproduced: the interpolation error x^6-type term is O(1) here.
  VectorXd ys6(n + 1);
  for (int i = 0; i <= n; ++i) ys6[i] = std::pow(xs[i], 6);
  EXPECT_GT(std::abs(sn::lagrange_interpolate(xs, ys6, 2.3) - std::pow(2.3, 6)), 1e-2);
}

TEST(PolynomialInterpolation, RejectsRepeatedNodes) {
  const VectorXd xs = (VectorXd(3) << 0.0, 1.0, 0.0).finished();
  const VectorXd ys = VectorXd::Ones(3);
  EXPECT_THROW(sn::lagrange_interpolate(xs, ys, 0.5), std::invalid_argument);
  EXPECT_THROW(sn::newton_divided_differences(xs, ys), std::invalid_argument);
  EXPECT_THROW(sn::newton_divided_differences(xs, VectorXd::Ones(2).eval()), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------
// Least squares
// ---------------------------------------------------------------------------------------------

TEST(LeastSquares, RecoversPolynomialFromNoisySamplesToNoiseLevel) {
  const double sigma = 1e-3;
  const VectorXd truth = (VectorXd(4) << 1.0, 2.0, -3.0, 0.5).finished();
  std::mt19937 rng(2024);
  std::normal_distribution<double> noise(0.0, sigma);
  const int n = 200;
  std::vector<double> xs(n);
  VectorXd ys(n);
  for (int i = 0; i < n; ++i) {
    xs[i] = static_cast<double>(i) / (n - 1);
    ys[i] = horner(truth, xs[i]) + noise(rng);
  }
  const auto basis = sn::monomial_basis<double>(3);
  const VectorXd c = sn::least_squares_fit(xs, ys, basis);
  double max_fit_err = 0, rss = 0;
  for (int i = 0; i < n; ++i) {
    max_fit_err = std::max(max_fit_err, std::abs(horner(c, xs[i]) - horner(truth, xs[i])));
    rss += std::pow(horner(c, xs[i]) - ys[i], 2);
  }
  const double rms_residual = std::sqrt(rss / (n - 4));
  std::cout << "[lsq] max |fit - truth| = " << max_fit_err << ", rms residual = " << rms_residual
            << " (sigma = " << sigma << ")\n";
  // The fitted curve's error has standard deviation ~ sigma sqrt(m / n) = 0.14 sigma: below sigma.
  EXPECT_LT(max_fit_err, sigma);
  // The residual estimates sigma with relative spread 1/sqrt(2 (n - m)) = 5%: allow 20%.
  EXPECT_NEAR(rms_residual, sigma, 0.2 * sigma);
}

TEST(LeastSquares, ZeroWeightsIgnoreOutliers) {
  const VectorXd truth = (VectorXd(3) << -0.5, 1.0, 2.0).finished();
  const int n = 40;
  std::vector<double> xs(n);
  VectorXd ys(n), w = VectorXd::Ones(n);
  for (int i = 0; i < n; ++i) {
    xs[i] = -1.0 + 2.0 * i / (n - 1);
    ys[i] = horner(truth, xs[i]);
    if (i % 7 == 3) {
      ys[i] += 5.0;  // outlier
      w[i] = 0.0;
    }
  }
  const auto basis = sn::monomial_basis<double>(2);
  const VectorXd weighted = sn::weighted_least_squares_fit(xs, ys, w, basis);
  const VectorXd unweighted = sn::least_squares_fit(xs, ys, basis);
  EXPECT_LT((weighted - truth).norm(), 1e-12);  // exact data on the kept samples, cond(A) ~ 10
  EXPECT_GT((unweighted - truth).norm(), 0.1);
}

TEST(LeastSquares, QrAndNormalEquationsAgreeWhenWellConditioned) {
  // Cubic on 50 points of [-1, 1]: cond(A) ~ 5, cond(A^T A) ~ 25, both methods exact to ~1e-15.
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<double> xs(50);
  VectorXd ys(50);
  for (int i = 0; i < 50; ++i) {
    xs[i] = u(rng);
    ys[i] = std::sin(2.0 * xs[i]);
  }
  const auto basis = sn::monomial_basis<double>(3);
  const VectorXd c_qr =
      sn::least_squares_fit(xs, ys, basis, sn::LeastSquaresMethod::kHouseholderQR);
  const VectorXd c_cp =
      sn::least_squares_fit(xs, ys, basis, sn::LeastSquaresMethod::kColPivHouseholderQR);
  const VectorXd c_ne =
      sn::least_squares_fit(xs, ys, basis, sn::LeastSquaresMethod::kNormalEquations);
  EXPECT_LT((c_qr - c_ne).norm() / c_qr.norm(), 1e-10);
  EXPECT_LT((c_qr - c_cp).norm() / c_qr.norm(), 1e-10);
}

TEST(LeastSquares, QrBeatsNormalEquationsOnIllConditionedVandermonde) {
  // Degree 12 monomials on 100 equispaced points of [0, 1]: cond(A) ~ 1e8-1e9, so QR loses
  // ~8 digits but the normal equations (cond^2 ~ 1e17 > 1/eps) lose all of them.
  const int degree = 12, n = 100;
  const VectorXd truth = VectorXd::Ones(degree + 1);
  std::vector<double> xs(n);
  VectorXd ys(n);
  for (int i = 0; i < n; ++i) {
    xs[i] = static_cast<double>(i) / (n - 1);
    ys[i] = horner(truth, xs[i]);
  }
  const auto basis = sn::monomial_basis<double>(degree);
  const double err_qr =
      (sn::least_squares_fit(xs, ys, basis, sn::LeastSquaresMethod::kHouseholderQR) - truth).norm();
  const double err_ne =
      (sn::least_squares_fit(xs, ys, basis, sn::LeastSquaresMethod::kNormalEquations) - truth)
          .norm();
  std::cout << "[lsq] Vandermonde degree 12: coefficient error QR = " << err_qr
            << ", normal equations = " << err_ne << "\n";
  EXPECT_LT(100.0 * err_qr, err_ne);
}

// ---------------------------------------------------------------------------------------------
// Moving least squares
// ---------------------------------------------------------------------------------------------

namespace {

// A polynomial of total degree `degree` in Dim variables with fixed, O(1) coefficients.
template <int Dim>
double test_polynomial(const Eigen::Vector<double, Dim>& x, int degree) {
  double v = 0.7;
  if (degree >= 1)
    for (int a = 0; a < Dim; ++a) v += (0.5 + 0.3 * a) * x[a];
  if (degree >= 2)
    for (int a = 0; a < Dim; ++a)
      for (int b = a; b < Dim; ++b) v += (a == b ? 1.1 : -0.6) * x[a] * x[b];
  if (degree >= 3) v += 2.0 * x[0] * x[0] * x[0];
  return v;
}

// Largest |MLS - p| at 20 random points of the inner box [0.2, 0.8]^Dim, for samples at N random
// points of [0, 1]^Dim taken from a polynomial of degree `data_degree`.
template <int Dim>
double mls_max_error(int basis_degree, int data_degree, sn::MlsWeight weight, double radius,
                     int samples, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0), inner(0.2, 0.8);
  std::vector<Eigen::Vector<double, Dim>> pts(static_cast<size_t>(samples));
  VectorXd vals(samples);
  for (int i = 0; i < samples; ++i) {
    for (int a = 0; a < Dim; ++a) pts[static_cast<size_t>(i)][a] = u01(rng);
    vals[i] = test_polynomial<Dim>(pts[static_cast<size_t>(i)], data_degree);
  }
  sn::MlsOptions<double> opt;
  opt.degree = basis_degree;
  opt.radius = radius;
  opt.weight = weight;
  const sn::MovingLeastSquares<double, Dim> mls(pts, vals, opt);
  double max_err = 0;
  for (int k = 0; k < 20; ++k) {
    Eigen::Vector<double, Dim> x;
    for (int a = 0; a < Dim; ++a) x[a] = inner(rng);
    max_err = std::max(max_err, std::abs(mls(x) - test_polynomial<Dim>(x, data_degree)));
  }
  return max_err;
}

}  // namespace

TEST(MovingLeastSquares, ReproducesPolynomialsOfItsBasisDegree) {
  // Radii keep >= ~10 samples per basis function inside the support, so the local systems have
  // condition numbers below ~1e3 and the reproduction error is round-off: < 1e-11 on values O(1).
  for (const auto weight : {sn::MlsWeight::kWendland, sn::MlsWeight::kGaussian}) {
    for (int degree = 0; degree <= 2; ++degree) {
      SCOPED_TRACE("degree " + std::to_string(degree) +
                   (weight == sn::MlsWeight::kWendland ? " Wendland" : " Gaussian"));
      EXPECT_LT(mls_max_error<1>(degree, degree, weight, 0.25, 40, 100 + degree), 1e-11);
      EXPECT_LT(mls_max_error<2>(degree, degree, weight, 0.3, 300, 200 + degree), 1e-11);
      EXPECT_LT(mls_max_error<3>(degree, degree, weight, 0.4, 600, 300 + degree), 1e-11);
    }
  }
}

TEST(MovingLeastSquares, DoesNotReproduceHigherDegree) {
  // The reproduction above is not vacuous: a degree-1 basis misses the quadratic terms by
  // ~ radius^2 (0.09 here), far above round-off.
  EXPECT_GT(mls_max_error<2>(1, 2, sn::MlsWeight::kWendland, 0.3, 300, 7), 1e-4);
  EXPECT_GT(mls_max_error<2>(2, 3, sn::MlsWeight::kWendland, 0.3, 300, 8), 1e-5);
}

TEST(MovingLeastSquares, ThrowsWhenTheLocalFitIsUnderdetermined) {
  std::vector<Vector2d> pts = {Vector2d(0, 0), Vector2d(1, 0), Vector2d(0, 1), Vector2d(1, 1)};
  const VectorXd vals = VectorXd::Ones(4);
  sn::MlsOptions<double> opt;
  opt.degree = 1;
  opt.radius = 0.3;  // only one sample within reach of a corner: 3 basis functions, rank 1
  const sn::MovingLeastSquares<double, 2> mls(pts, vals, opt);
  EXPECT_THROW(mls(Vector2d(0.05, 0.05)), std::domain_error);
  opt.degree = 3;
  EXPECT_THROW((sn::MovingLeastSquares<double, 2>(pts, vals, opt)), std::invalid_argument);
}
