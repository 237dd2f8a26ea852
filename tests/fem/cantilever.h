// A clamped cantilever released from its first bending mode shape: the measured period of the
// tip's vertical oscillation against Euler-Bernoulli, omega_1 = 1.8751^2 sqrt(E I / (rho A L^4)).
#pragma once
#include <cmath>
#include <memory>
#include <vector>

#include "slurry/engine/fem/corotated_fem.h"

namespace fem_test {

/// Holds the vertices listed in `held` at zero velocity.
template <class T, int Dim>
struct Clamp {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  std::vector<char> held;
  bool pin(int i, const Vec&, Vec& vb) const {
    vb.setZero();
    return held[std::size_t(i)] != 0;
  }
  void apply(int i, const Vec&, Vec& v) const {
    if (held[std::size_t(i)]) v.setZero();
  }
};

/// A beam [0, L] x [0, h] (x [0, h] in 3D) of E = 1e6 Pa, nu = 0, rho = 1000 kg/m^3 with
/// `across` elements through the thickness and cells as close to squares (cubes) as whole
/// numbers allow, clamped at x = 0 and displaced into its Euler-Bernoulli first mode (tip
/// amplitude 1e-3 L; the sections rotate with the slope), at rest.
template <int Dim>
struct Beam {
  using Vec = Eigen::Matrix<double, Dim, 1>;
  static constexpr double E = 1e6, rho = 1000;
  double L, h;
  std::unique_ptr<slurry::fem::CorotatedFem<double, Dim>> fem;
  Clamp<double, Dim> clamp;
  std::vector<int> tip;
  double omega_euler_bernoulli = 0;

  Beam(double L_, double h_, int across) : L(L_), h(h_) {
    Eigen::Matrix<int, Dim, 1> cells = Eigen::Matrix<int, Dim, 1>::Constant(across);
    cells[0] = int(std::lround(L / h * across));
    Vec hi = Vec::Constant(h);
    hi[0] = L;
    const auto mesh = slurry::fem::box_mesh<Dim>(Vec::Zero(), hi, cells);
    fem = std::make_unique<slurry::fem::CorotatedFem<double, Dim>>(mesh, slurry::fem::FemMaterial<double>::from_young(E, 0.0, rho));
    clamp.held.resize(fem->vertex_count());
    // Euler-Bernoulli first mode phi(s), s = x / L, and its slope.
    const double beta = 1.87510407, sg = (std::cosh(beta) + std::cos(beta)) / (std::sinh(beta) + std::sin(beta));
    const auto phi = [&](double s) {
      return std::cosh(beta * s) - std::cos(beta * s) - sg * (std::sinh(beta * s) - std::sin(beta * s));
    };
    const auto dphi = [&](double s) {
      return beta * (std::sinh(beta * s) + std::sin(beta * s) - sg * (std::cosh(beta * s) - std::cos(beta * s)));
    };
    const double amplitude = 1e-3 * L / phi(1.0);
    for (std::size_t i = 0; i < fem->vertex_count(); ++i) {
      const Vec X = fem->rest()[i];
      clamp.held[i] = X[0] < 1e-12;
      if (X[0] > L - 1e-12) tip.push_back(int(i));
      const double s = X[0] / L;
      fem->x[i][1] += amplitude * phi(s);
      fem->x[i][0] -= amplitude * dphi(s) / L * (X[1] - h / 2);
    }
    const double A = Dim == 2 ? h : h * h, I = Dim == 2 ? h * h * h / 12 : h * h * h * h / 12;
    omega_euler_bernoulli = beta * beta * std::sqrt(E * I / (rho * A * L * L * L * L));
  }
  /// Mean vertical displacement of the tip vertices.
  double tip_y() const {
    double y = 0;
    for (int i : tip) y += fem->x[std::size_t(i)][1] - fem->rest()[std::size_t(i)][1];
    return y / double(tip.size());
  }
  void step(double dt, bool implicit) {
    if (implicit)
      fem->step_implicit(dt, Vec::Zero(), clamp);
    else
      fem->step_symplectic(dt, Vec::Zero(), clamp);
  }
};

struct CantileverResult {
  double omega_measured = 0, omega_euler_bernoulli = 0, relative_error = 0;
  long steps = 0;
  int elements = 0;
};

/// The beam's first bending frequency from three zero crossings of the tip (one full period,
/// linear interpolation between steps), with symplectic Euler at 0.9 times its stability limit.
template <int Dim>
CantileverResult cantilever_frequency(double L, double h, int across) {
  Beam<Dim> beam(L, h, across);
  CantileverResult r;
  r.elements = int(beam.fem->element_count());
  r.omega_euler_bernoulli = beam.omega_euler_bernoulli;
  const double dt = beam.fem->explicit_dt(0.9);
  std::vector<double> crossings;
  double prev = beam.tip_y(), t = 0;
  const double t_max = 3 * 2 * M_PI / r.omega_euler_bernoulli;
  while (crossings.size() < 3 && t < t_max) {
    beam.step(dt, false);
    t += dt;
    ++r.steps;
    const double y = beam.tip_y();
    if ((prev > 0) != (y > 0)) crossings.push_back(t - dt * y / (y - prev));
    prev = y;
  }
  if (crossings.size() < 3) return r;
  r.omega_measured = 2 * M_PI / (crossings[2] - crossings[0]);
  r.relative_error = r.omega_measured / r.omega_euler_bernoulli - 1;
  return r;
}

}  // namespace fem_test
