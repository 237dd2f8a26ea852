// Validation of the FLIP liquid's viscosity at sizes too slow for CI (label "validation"): the
// damping of a standing wave against Lamb's rate. It does not pass yet: the viscous part of the
// decay is +30.8% off at dx = 1/64 (+4.5% at 1/48), not converging with dx, while the viscous
// operator alone dissipates 0.95 of 2 mu int |D|^2 on the same wave's potential flow; the
// inviscid run's own damping (0.13 1/s) and the particles' noise at the surface do not add up
// linearly with the viscous damping.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "slurry/engine/flip/flip_solver.h"

namespace {

using slurry::Scene;

/// A 2D double-precision FLIP scene over [0, w] x [0, h] with one liquid of viscosity mu.
Scene viscous_scene(double w, double h, double dx, double mu) {
  Scene s;
  s.source = "test";
  s.solver.type = slurry::SolverType::FLIP;
  s.solver.dimension = 2;
  s.solver.precision = slurry::Precision::Double;
  s.solver.transfer = slurry::TransferKind::APIC;
  s.solver.kernel = slurry::KernelKind::Linear;
  s.solver.cfl = 1;
  s.solver.max_dt = 1.0 / 240;
  s.solver.pressure.tolerance = 1e-8;
  s.domain.max = {w, h, 0};
  s.domain.dx = dx;
  slurry::MaterialParams m;
  m.name = "liquid";
  m.model = slurry::ElasticModel::Fluid;
  m.density = 1000;
  m.viscosity = mu;
  s.materials = {m};
  slurry::BodyParams b;
  b.shape = slurry::Shape::Box;
  b.max = {w, 0, 0};
  b.material = "liquid";
  b.particles_per_cell = 4;
  s.bodies = {b};
  return s;
}

/// Decay rate (1/s) of a standing wave (mode k = pi / L in a tank of free-slip walls, depth
/// h = L / 2) from the first four peaks of the horizontal centre of mass, which oscillates with
/// the wave: a least-squares line through log |peak| against time. (With free-slip walls and
/// bottom the potential flow's dissipation 2 mu int |D|^2 gives the amplitude rate 2 nu k^2 at
/// any depth; the later peaks are dominated by the particles' noise.)
double standing_wave_decay_rate(double mu, double dx) {
  const double L = 1, h = 0.5, g = 9.81, amp = 0.02;
  Scene s = viscous_scene(L, 0.75, dx, mu);
  s.bodies[0].max = {L, h, 0};
  slurry::flip::FlipSolver<double, 2> sim(s);
  const double k = M_PI / L, omega = std::sqrt(g * k * std::tanh(k * h)), period = 2 * M_PI / omega;
  auto& P = sim.particles();
  for (std::size_t p = 0; p < P.size(); ++p) {
    const double x = P.x[p][0], y = P.x[p][1], a = amp * omega / std::sinh(k * h);
    // The linear mode's potential flow, phi = (a / k) cos(k x) cosh(k y).
    P.v[p] = {-a * std::sin(k * x) * std::cosh(k * y), a * std::cos(k * x) * std::sinh(k * y)};
    if (P.affine) {
      P.c[0][p] = {-a * k * std::cos(k * x) * std::cosh(k * y), -a * k * std::sin(k * x) * std::sinh(k * y)};
      P.c[1][p] = {-a * k * std::sin(k * x) * std::sinh(k * y), a * k * std::cos(k * x) * std::cosh(k * y)};
    }
  }
  const auto x_cm = [&] {
    double sum = 0;
    for (const auto& x : sim.particles().x) sum += x[0];
    return sum / double(sim.particles().size());
  };
  const double x0 = x_cm(), dt = 1.0 / 240;
  std::vector<double> t, d;
  while (sim.time() < 2 * period) {
    sim.advance_to(sim.time() + dt);
    t.push_back(sim.time());
    d.push_back(x_cm() - x0);
  }
  // Peaks of |d| (a parabola through the three samples around each extremum).
  std::vector<double> pt, pa;
  for (std::size_t i = 1; i + 1 < d.size() && pt.size() < 4; ++i) {
    const double a0 = std::abs(d[i - 1]), a1 = std::abs(d[i]), a2 = std::abs(d[i + 1]);
    if (a1 >= a0 && a1 > a2 && (d[i] > 0) == (d[i - 1] > 0) && (d[i] > 0) == (d[i + 1] > 0)) {
      const double den = a0 - 2 * a1 + a2, off = den != 0 ? 0.5 * (a0 - a2) / den : 0;
      pt.push_back(t[i] + off * dt);
      pa.push_back(std::log(a1 - 0.25 * (a0 - a2) * off));
    }
  }
  EXPECT_GE(pt.size(), 4u);
  if (pt.size() < 2) return 0;
  double mt = 0, ma = 0;
  for (std::size_t i = 0; i < pt.size(); ++i) mt += pt[i], ma += pa[i];
  mt /= double(pt.size()), ma /= double(pt.size());
  double num = 0, den = 0;
  for (std::size_t i = 0; i < pt.size(); ++i) num += (pt[i] - mt) * (pa[i] - ma), den += (pt[i] - mt) * (pt[i] - mt);
  return -num / den;
}

// Lamb, "Hydrodynamics", 6th ed., sec. 348: a small wave on a liquid of kinematic viscosity nu
// decays as exp(-2 nu k^2 t) (nu k^2 / omega << 1; here 0.02). The solver's own damping of the
// inviscid wave (APIC, the free surface's resolution) is measured beside it and subtracted.
TEST(FlipViscosityValidation, StandingWaveDampsAtLambsRate) {
  const double dx = 1.0 / 64, mu = 10, nu = mu / 1000, k = M_PI;
  const double inviscid = standing_wave_decay_rate(0, dx);
  const double viscous = standing_wave_decay_rate(mu, dx);
  const double lamb = 2 * nu * k * k;
  const double measured = viscous - inviscid;
  std::printf("[ figure ] standing wave dx = 1/%.0f, nu = %.3g m^2/s: decay rate %.4f 1/s (inviscid run %.4f), viscous part "
              "%.4f vs 2 nu k^2 = %.4f: %+.1f%%\n",
              1 / dx, nu, viscous, inviscid, measured, lamb, 100 * (measured / lamb - 1));
  EXPECT_NEAR(measured / lamb, 1, 0.10);
}

}  // namespace
