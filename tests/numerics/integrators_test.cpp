// Tests of slurry/engine/numerics/integrators.h: observed orders, long-time energy behaviour,
// stability limits of the explicit schemes and unconditional stability of the implicit ones.
#include "slurry/engine/numerics/integrators.h"

#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <vector>

#include "numerics/convergence.h"

namespace sn = slurry::numerics;
using Eigen::VectorXd;
using slurry::numerics::test::report_order;

namespace {

const double kPi = 3.14159265358979323846;

// Fitted orders over dt = T/10 .. T/80 are within a few hundredths of the theoretical ones for
// these smooth problems (checked by the printed tables); +-0.2 as asked catches a wrong stage.
constexpr double kOrderTolerance = 0.2;

VectorXd vec1(double a) {
  return VectorXd::Constant(1, a);
}

// Undamped spring f = -k x on one mass.
struct Spring {
  double k;
  VectorXd operator()(const VectorXd& x, const VectorXd& /*v*/) const { return -k * x; }
};

double spring_energy(const sn::MechanicalState<double>& s, double m, double k) {
  return 0.5 * m * s.v.squaredNorm() + 0.5 * k * s.x.squaredNorm();
}

sn::ForceJacobian<double> spring_jacobian(Eigen::Index n, double k) {
  sn::ForceJacobian<double> j;
  j.dfdx.resize(n, n);
  j.dfdx.setIdentity();
  j.dfdx *= -k;
  j.dfdv.resize(n, n);
  return j;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// First-order systems
// ---------------------------------------------------------------------------------------------

TEST(FirstOrderIntegrators, ObservedOrdersOnExponentialDecay) {
  // y' = lambda y, y(0) = 1, exact exp(lambda t); scalar state.
  const double lambda = -2.0, t_end = 1.0;
  const auto f = [lambda](double /*t*/, double y) { return lambda * y; };
  const double exact = std::exp(lambda * t_end);
  std::vector<double> hs, e_euler, e_heun, e_mid, e_rk4;
  for (int n : {10, 20, 40, 80}) {
    const double dt = t_end / n;
    double y1 = 1, y2 = 1, y3 = 1, y4 = 1;
    for (int k = 0; k < n; ++k) {
      const double t = k * dt;
      y1 = sn::euler_step(f, t, y1, dt);
      y2 = sn::heun_step(f, t, y2, dt);
      y3 = sn::midpoint_step(f, t, y3, dt);
      y4 = sn::rk4_step(f, t, y4, dt);
    }
    hs.push_back(dt);
    e_euler.push_back(std::abs(y1 - exact));
    e_heun.push_back(std::abs(y2 - exact));
    e_mid.push_back(std::abs(y3 - exact));
    e_rk4.push_back(std::abs(y4 - exact));
  }
  EXPECT_NEAR(report_order("decay_euler", hs, e_euler), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("decay_heun", hs, e_heun), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("decay_midpoint", hs, e_mid), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("decay_rk4", hs, e_rk4), 4.0, kOrderTolerance);
}

TEST(FirstOrderIntegrators, ObservedOrdersOnHarmonicOscillator) {
  // y = (x, v), y' = (v, -omega^2 x) with a time-dependent forcing to exercise t: + (0, sin t).
  const double omega = 2.0, t_end = 2.0;
  const auto f = [omega](double t, const VectorXd& y) {
    VectorXd d(2);
    d << y[1], -omega * omega * y[0] + std::sin(t);
    return d;
  };
  // Exact solution for x(0) = 1, v(0) = 0: x = A cos(wt) + B sin(wt) + sin(t) / (w^2 - 1).
  const double c = 1.0 / (omega * omega - 1.0);
  const auto exact = [&](double t) {
    VectorXd e(2);
    const double b = -c / omega;
    e << std::cos(omega * t) + b * std::sin(omega * t) + c * std::sin(t),
        -omega * std::sin(omega * t) + b * omega * std::cos(omega * t) + c * std::cos(t);
    return e;
  };
  std::vector<double> hs, e_euler, e_heun, e_mid, e_rk4;
  for (int n : {20, 40, 80, 160}) {
    const double dt = t_end / n;
    VectorXd y0(2);
    y0 << 1.0, 0.0;
    VectorXd y1 = y0, y2 = y0, y3 = y0, y4 = y0;
    for (int k = 0; k < n; ++k) {
      const double t = k * dt;
      y1 = sn::euler_step(f, t, y1, dt);
      y2 = sn::heun_step(f, t, y2, dt);
      y3 = sn::midpoint_step(f, t, y3, dt);
      y4 = sn::rk4_step(f, t, y4, dt);
    }
    const VectorXd ye = exact(t_end);
    hs.push_back(dt);
    e_euler.push_back((y1 - ye).norm());
    e_heun.push_back((y2 - ye).norm());
    e_mid.push_back((y3 - ye).norm());
    e_rk4.push_back((y4 - ye).norm());
  }
  EXPECT_NEAR(report_order("oscillator_euler", hs, e_euler), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("oscillator_heun", hs, e_heun), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("oscillator_midpoint", hs, e_mid), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("oscillator_rk4", hs, e_rk4), 4.0, kOrderTolerance);
}

// ---------------------------------------------------------------------------------------------
// Mechanical integrators: orders
// ---------------------------------------------------------------------------------------------

TEST(MechanicalIntegrators, ObservedOrdersOnDampedOscillator) {
  // m x'' = -k x - c v, m = 2, k = 8, c = 0.4: underdamped, omega_d = sqrt(k/m - zeta^2).
  const double m = 2.0, k = 8.0, c = 0.4, t_end = 1.0;
  const auto force = [k, c](const VectorXd& x, const VectorXd& v) -> VectorXd {
    return -k * x - c * v;
  };
  const auto jac = [k, c](const VectorXd& x, const VectorXd&) {
    sn::ForceJacobian<double> j = spring_jacobian(x.size(), k);
    j.dfdv.setIdentity();
    j.dfdv *= -c;
    return j;
  };
  const double gamma = c / (2 * m), wd = std::sqrt(k / m - gamma * gamma);
  // x(0) = 1, v(0) = 0: x = e^{-gamma t} (cos wd t + gamma / wd sin wd t).
  const double xe =
      std::exp(-gamma * t_end) * (std::cos(wd * t_end) + gamma / wd * std::sin(wd * t_end));
  const double ve = -std::exp(-gamma * t_end) * (k / m) / wd * std::sin(wd * t_end);
  const VectorXd mass = vec1(m);
  std::vector<double> hs, e_exp, e_sym, e_imp, e_be, e_li;
  for (int n : {40, 80, 160, 320}) {
    const double dt = t_end / n;
    sn::MechanicalState<double> s0{vec1(1.0), vec1(0.0)};
    auto s_exp = s0, s_sym = s0, s_imp = s0, s_be = s0, s_li = s0;
    for (int i = 0; i < n; ++i) {
      sn::explicit_euler_step(force, mass, s_exp, dt);
      sn::symplectic_euler_step(force, mass, s_sym, dt);
      sn::improved_euler_step(force, mass, s_imp, dt);
      EXPECT_TRUE(sn::backward_euler_step(force, jac, mass, s_be, dt).converged);
      sn::linearly_implicit_euler_step(force, jac, mass, s_li, dt);
    }
    const auto err = [&](const sn::MechanicalState<double>& s) {
      return std::hypot(s.x[0] - xe, s.v[0] - ve);
    };
    hs.push_back(dt);
    e_exp.push_back(err(s_exp));
    e_sym.push_back(err(s_sym));
    e_imp.push_back(err(s_imp));
    e_be.push_back(err(s_be));
    e_li.push_back(err(s_li));
  }
  EXPECT_NEAR(report_order("mech_explicit_euler", hs, e_exp), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("mech_symplectic_euler", hs, e_sym), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("mech_improved_euler", hs, e_imp), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("mech_backward_euler", hs, e_be), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("mech_linearly_implicit_euler", hs, e_li), 1.0, kOrderTolerance);
}

// ---------------------------------------------------------------------------------------------
// Long-time energy behaviour on the undamped oscillator, omega = 1, 100 steps per period
// ---------------------------------------------------------------------------------------------

namespace {
constexpr int kStepsPerPeriod = 100;
const double kDt = 2 * kPi / kStepsPerPeriod;  // z = omega dt = 0.0628
}  // namespace

TEST(EnergyBehaviour, SymplecticEulerStaysBoundedOver1e4Periods) {
  const Spring force{1.0};
  const VectorXd mass = vec1(1.0);
  sn::MechanicalState<double> s{vec1(1.0), vec1(0.0)};
  const double e0 = spring_energy(s, 1.0, 1.0);
  const long periods = 10000;
  double max_first = 0, max_last = 0, max_all = 0;
  for (long p = 0; p < periods; ++p) {
    for (int i = 0; i < kStepsPerPeriod; ++i) {
      sn::symplectic_euler_step(force, mass, s, kDt);
      const double rel = std::abs(spring_energy(s, 1.0, 1.0) / e0 - 1.0);
      max_all = std::max(max_all, rel);
      if (p == 0) max_first = std::max(max_first, rel);
      if (p == periods - 1) max_last = std::max(max_last, rel);
    }
  }
  std::cout << "[energy] symplectic Euler, 1e4 periods: max |E/E0 - 1| = " << max_all
            << " (first period " << max_first << ", last period " << max_last << ")\n";
  // Symplectic Euler conserves a modified energy H - (dt/2) omega^2 x v exactly, so the true
  // energy oscillates within relative O(z / 2) = 0.031 forever; bound it by z = 0.063.
  EXPECT_LT(max_all, kDt);
  // No secular drift: the oscillation in the last period matches the first within 1%.
  EXPECT_NEAR(max_last, max_first, 0.01 * max_first);
}

TEST(EnergyBehaviour, ExplicitEulerEnergyGrowsGeometrically) {
  // Each explicit Euler step multiplies the energy of the undamped oscillator by exactly
  // 1 + z^2; at this dt that overflows after ~180 periods, so we follow 100 periods.
  const Spring force{1.0};
  const VectorXd mass = vec1(1.0);
  sn::MechanicalState<double> s{vec1(1.0), vec1(0.0)};
  const double e0 = spring_energy(s, 1.0, 1.0);
  double previous = 1.0;
  long steps = 0;
  for (int checkpoint = 1; checkpoint <= 10; ++checkpoint) {
    for (int i = 0; i < 10 * kStepsPerPeriod; ++i, ++steps)
      sn::explicit_euler_step(force, mass, s, kDt);
    const double ratio = spring_energy(s, 1.0, 1.0) / e0;
    const double analytic = std::pow(1.0 + kDt * kDt, static_cast<double>(steps));
    EXPECT_GT(ratio, previous);
    // Round-off grows like steps * eps ~ 1e-12 relative; 1e-8 leaves a wide margin.
    EXPECT_NEAR(ratio / analytic, 1.0, 1e-8);
    previous = ratio;
  }
  std::cout << "[energy] explicit Euler after 100 periods: E/E0 = " << previous << "\n";
  EXPECT_GT(previous, 1e10);
}

TEST(EnergyBehaviour, ImprovedEulerDriftsWithoutBound) {
  // Heun's amplification factor on the oscillator has modulus^2 = 1 + z^4 / 4 > 1, so the energy
  // grows monotonically: after 1e6 steps by exp(1e6 z^4 / 4) ~ 49.
  const Spring force{1.0};
  const VectorXd mass = vec1(1.0);
  sn::MechanicalState<double> s{vec1(1.0), vec1(0.0)};
  const double e0 = spring_energy(s, 1.0, 1.0);
  const double per_step = 1.0 + std::pow(kDt, 4) / 4.0;
  double previous = 1.0;
  long steps = 0;
  for (int checkpoint = 1; checkpoint <= 10; ++checkpoint) {
    for (int i = 0; i < 1000 * kStepsPerPeriod; ++i, ++steps)
      sn::improved_euler_step(force, mass, s, kDt);
    const double ratio = spring_energy(s, 1.0, 1.0) / e0;
    std::cout << "[energy] improved Euler after " << checkpoint * 1000
              << " periods: E/E0 = " << ratio << "\n";
    EXPECT_GT(ratio, previous);  // monotone growth at every checkpoint
    // Relative round-off after 1e6 steps stays ~1e-10; 1e-6 leaves a wide margin.
    EXPECT_NEAR(ratio / std::pow(per_step, static_cast<double>(steps)), 1.0, 1e-6);
    previous = ratio;
  }
  EXPECT_GT(previous, 10.0);
}

// ---------------------------------------------------------------------------------------------
// Stability limits on the zero-length spring f = -k x
// ---------------------------------------------------------------------------------------------
// Symplectic Euler on m x'' = -k x has the amplification matrix [[1 - z^2, dt], [-w^2 dt, 1]]
// (z = omega dt) with determinant 1 and trace 2 - z^2: stable iff |2 - z^2| < 2, i.e.
// dt < 2 / omega = 2 sqrt(m / k). That is the limit tested here. (The sqrt(2 m / k) sometimes
// quoted is neither method's limit; explicit Euler has none: |1 + i z| > 1 for every dt > 0, so
// on an undamped spring it diverges at any step.)

namespace {
constexpr double kMass = 1.0, kStiffness = 4.0;             // omega = 2
const double kLimit = 2.0 * std::sqrt(kMass / kStiffness);  // = 1

double max_amplitude(double dt, int steps, bool symplectic) {
  const Spring force{kStiffness};
  const VectorXd mass = vec1(kMass);
  sn::MechanicalState<double> s{vec1(1.0), vec1(0.0)};
  double amp = 0;
  for (int i = 0; i < steps; ++i) {
    if (symplectic)
      sn::symplectic_euler_step(force, mass, s, dt);
    else
      sn::explicit_euler_step(force, mass, s, dt);
    amp = std::max(amp, std::abs(s.x[0]));
  }
  return amp;
}
}  // namespace

TEST(StabilityLimit, SymplecticEulerDivergesJustAboveTwoOverOmega) {
  // Just above: eigenvalue modulus 1.49 at dt = 1.02 dt*, so 200 steps amplify by ~1e34.
  const double above = max_amplitude(1.02 * kLimit, 200, true);
  // Just below: the invariant quadratic form confines |x| to x0 / sqrt(1 - z^2/4) ~ 5 x0 at
  // dt = 0.98 dt*; 10^4 steps and a bound of 10 x0.
  const double below = max_amplitude(0.98 * kLimit, 10000, true);
  std::cout << "[stability] symplectic Euler max |x|: dt = 1.02 dt* -> " << above
            << ", dt = 0.98 dt* -> " << below << "\n";
  EXPECT_GT(above, 1e10);
  EXPECT_LT(below, 10.0);
}

TEST(StabilityLimit, ExplicitEulerDivergesAtAnyStepOnAnUndampedSpring) {
  // |amplification| = sqrt(1 + z^2): 1.40 per step at 0.98 dt*, 1.0002 per step at 0.01 dt*.
  EXPECT_GT(max_amplitude(0.98 * kLimit, 200, false), 1e10);
  EXPECT_GT(max_amplitude(0.01 * kLimit, 20000, false), 1.5);  // (1 + 4e-4)^(1e4) ~ e^4 = 55
}

TEST(StabilityLimit, ImplicitEulerBoundedAt100TimesTheLimit) {
  const double dt = 100.0 * kLimit;
  const VectorXd mass = vec1(kMass);
  Eigen::SparseMatrix<double> k(1, 1), d(1, 1);
  k.insert(0, 0) = kStiffness;
  const VectorXd zero = vec1(0.0);
  const Spring force{kStiffness};
  const auto jac = [](const VectorXd& x, const VectorXd&) {
    return spring_jacobian(x.size(), kStiffness);
  };
  sn::MechanicalState<double> s_lin{vec1(1.0), vec1(0.0)};
  sn::MechanicalState<double> s_gen = s_lin, s_be = s_lin;
  double e_prev = spring_energy(s_lin, kMass, kStiffness);
  const double e0 = e_prev;
  for (int i = 0; i < 1000; ++i) {
    sn::linear_spring_implicit_euler_step(mass, k, d, zero, zero, s_lin, dt);
    sn::linearly_implicit_euler_step(force, jac, mass, s_gen, dt);
    sn::backward_euler_step(force, jac, mass, s_be, dt);
    const double e = spring_energy(s_lin, kMass, kStiffness);
    // Backward Euler's amplification has modulus 1 / sqrt(1 + z^2) < 1 in the energy norm.
    EXPECT_LE(e, e_prev * (1 + 1e-12));
    e_prev = e;
    ASSERT_TRUE(std::isfinite(s_gen.x[0]) && std::isfinite(s_be.x[0]));
  }
  EXPECT_LE(e_prev, e0);
  EXPECT_LT(std::abs(s_gen.x[0]), 1.0);
  EXPECT_LT(std::abs(s_be.x[0]), 1.0);
}

// ---------------------------------------------------------------------------------------------
// Implicit steps: agreement between the formulations, Newton with a finite-difference Jacobian
// ---------------------------------------------------------------------------------------------

namespace {

// A chain of 6 masses joined by springs (tridiagonal K), Rayleigh damping D = 0.1 K, gravity.
struct Chain {
  Eigen::SparseMatrix<double> k, d;
  VectorXd mass, x_rest, f_ext;
  explicit Chain(int n) : k(n, n), d(n, n), mass(n), x_rest(n), f_ext(n) {
    std::vector<Eigen::Triplet<double>> t;
    for (int i = 0; i < n; ++i) {
      t.emplace_back(i, i, 2.0 * 50.0);
      if (i > 0) t.emplace_back(i, i - 1, -50.0);
      if (i < n - 1) t.emplace_back(i, i + 1, -50.0);
      mass[i] = 0.5 + 0.1 * i;
      x_rest[i] = 0.2 * i;
      f_ext[i] = -9.81 * mass[i];
    }
    k.setFromTriplets(t.begin(), t.end());
    d = 0.1 * k;
  }
  VectorXd operator()(const VectorXd& x, const VectorXd& v) const {
    return -(k * (x - x_rest)) - d * v + f_ext;
  }
};

}  // namespace

TEST(ImplicitSteps, LinearlyImplicitAndBackwardEulerMatchTheLinearSpringStep) {
  const Chain chain(6);
  const auto jac = [&chain](const VectorXd&, const VectorXd&) {
    sn::ForceJacobian<double> j;
    j.dfdx = -chain.k;
    j.dfdv = -chain.d;
    return j;
  };
  sn::MechanicalState<double> s0{chain.x_rest + VectorXd::LinSpaced(6, 0.1, -0.2),
                                 VectorXd::LinSpaced(6, 1.0, -1.0)};
  auto s_lin = s0, s_gen = s0, s_be = s0;
  for (int i = 0; i < 20; ++i) {
    sn::linear_spring_implicit_euler_step(chain.mass, chain.k, chain.d, chain.x_rest, chain.f_ext,
                                          s_lin, 0.05);
    sn::linearly_implicit_euler_step(chain, jac, chain.mass, s_gen, 0.05);
    const auto r = sn::backward_euler_step(chain, jac, chain.mass, s_be, 0.05);
    EXPECT_TRUE(r.converged);
    EXPECT_EQ(r.newton_iterations, 1);  // linear force: Newton is exact in one step
  }
  // Same linear system solved by LDLT vs LU: agreement to ~cond * eps, cond(A) ~ 1e2.
  EXPECT_LT((s_lin.x - s_gen.x).norm(), 1e-12);
  EXPECT_LT((s_lin.v - s_gen.v).norm(), 1e-12);
  EXPECT_LT((s_lin.x - s_be.x).norm(), 1e-10);
  EXPECT_LT((s_lin.v - s_be.v).norm(), 1e-10);
}

TEST(ImplicitSteps, NewtonOnNonlinearForceWithAnalyticAndFiniteDifferenceJacobians) {
  // Hardening springs f_i = -(x_i + 4 x_i^3) - 0.2 v_i^3 (nonlinear in x and v).
  const auto force = [](const VectorXd& x, const VectorXd& v) -> VectorXd {
    return -(x.array() + 4.0 * x.array().cube()).matrix() - (0.2 * v.array().cube()).matrix();
  };
  const auto analytic = [](const VectorXd& x, const VectorXd& v) {
    sn::ForceJacobian<double> j;
    const Eigen::Index n = x.size();
    j.dfdx.resize(n, n);
    j.dfdv.resize(n, n);
    for (Eigen::Index i = 0; i < n; ++i) {
      j.dfdx.insert(i, i) = -(1.0 + 12.0 * x[i] * x[i]);
      j.dfdv.insert(i, i) = -0.6 * v[i] * v[i];
    }
    return j;
  };
  const VectorXd mass = VectorXd::Constant(3, 1.5);
  sn::MechanicalState<double> s0{(VectorXd(3) << 1.0, -0.5, 0.25).finished(),
                                 (VectorXd(3) << 0.0, 2.0, -1.0).finished()};
  auto s_an = s0, s_fd = s0;
  const double dt = 0.2;
  for (int i = 0; i < 10; ++i) {
    const auto ra = sn::backward_euler_step(force, analytic, mass, s_an, dt);
    const auto rf = sn::backward_euler_step(force, sn::finite_difference_jacobian<double>(force),
                                            mass, s_fd, dt);
    EXPECT_TRUE(ra.converged);
    EXPECT_TRUE(rf.converged);
    EXPECT_LE(ra.newton_iterations, 8);  // quadratic convergence to 1e-10 from a nearby start
    // The residual of the returned state is below the tolerance (relative to the initial one).
    EXPECT_LE(ra.residual, 1e-10);
  }
  // Both solve the same nonlinear equations to 1e-10 relative residual; the Jacobian only
  // changes the path, so the states agree to ~1e-10.
  EXPECT_LT((s_an.x - s_fd.x).norm(), 1e-9);
  EXPECT_LT((s_an.v - s_fd.v).norm(), 1e-9);
  // The finite-difference Jacobian matches the analytic one to O(eps^2) + round-off / eps.
  const auto jf = sn::finite_difference_jacobian<double>(force)(s0.x, s0.v);
  const auto ja = analytic(s0.x, s0.v);
  EXPECT_LT((Eigen::MatrixXd(jf.dfdx) - Eigen::MatrixXd(ja.dfdx)).norm(), 1e-7);
  EXPECT_LT((Eigen::MatrixXd(jf.dfdv) - Eigen::MatrixXd(ja.dfdv)).norm(), 1e-7);
}
