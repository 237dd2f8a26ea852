#pragma once
// The drops of the surface tension tests: a disk (2D) or ball (3D) of radius R = 0.25 m at the
// centre of the unit box, without gravity, liquid of density 1000 kg/m^3 and surface tension
// sigma, APIC with the linear kernel; the substep is the capillary limit (surface_tension.h).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/scene/scene.h"

namespace slurry_test {

constexpr double kDropRadius = 0.25, kDropDensity = 1000;

/// The drop's scene: dx = R / cells_per_radius; dynamic viscosity mu (Pa s).
template <int Dim>
slurry::Scene drop_scene(int cells_per_radius, double sigma, double mu = 0) {
  slurry::Scene s;
  s.source = "drop";
  s.solver.type = slurry::SolverType::FLIP;
  s.solver.dimension = Dim;
  s.solver.precision = slurry::Precision::Double;
  s.solver.transfer = slurry::TransferKind::APIC;
  s.solver.kernel = slurry::KernelKind::Linear;
  s.solver.cfl = 1;
  s.solver.max_dt = 1;  // the capillary limit and the CFL condition set the step
  s.solver.gravity = {0, 0, 0};
  s.solver.pressure.tolerance = 1e-8;
  s.domain.max = Dim == 3 ? Eigen::Vector3d(1, 1, 1) : Eigen::Vector3d(1, 1, 0);
  s.domain.dx = kDropRadius / cells_per_radius;
  slurry::MaterialParams m;
  m.name = "liquid";
  m.model = slurry::ElasticModel::Fluid;
  m.density = kDropDensity;
  m.surface_tension = sigma;
  m.viscosity = mu;
  s.materials = {m};
  slurry::BodyParams b;
  b.shape = slurry::Shape::Sphere;
  b.center = Dim == 3 ? Eigen::Vector3d(0.5, 0.5, 0.5) : Eigen::Vector3d(0.5, 0.5, 0);
  b.radius = kDropRadius;
  b.material = "liquid";
  b.particles_per_cell = Dim == 3 ? 8 : 4;
  s.bodies = {b};
  return s;
}

/// Keeps, in their order, the particles of P whose position x satisfies inside(x).
template <class Particles, class Inside>
void keep_particles(Particles& P, Inside&& inside) {
  std::size_t kept = 0;
  for (std::size_t p = 0; p < P.size(); ++p)
    if (inside(P.x[p])) P.move(kept++, p);
  P.truncate(kept);
}

/// The drop's scene with a box collider filling the domain below y = floor (none for floor 0:
/// the domain's floor is the wall).
template <int Dim>
slurry::Scene drop_on_a_wall_scene(int cells_per_radius, double sigma, double floor) {
  slurry::Scene s = drop_scene<Dim>(cells_per_radius, sigma);
  if (floor > 0) {
    slurry::ColliderParams c;
    c.shape = slurry::ColliderShape::Box;
    c.min = Eigen::Vector3d(-1, -1, -1);
    c.max = Eigen::Vector3d(2, floor, 2);
    s.colliders = {c};
  }
  return s;
}

/// Cuts the drop of `sim` to its upper half and lowers that onto the wall at y = floor: a half
/// drop of radius R centred on (0.5, floor[, 0.5]).
template <class Sim>
void half_drop_on_the_wall(Sim& sim, double floor) {
  auto& P = sim.particles();
  keep_particles(P, [](const auto& x) { return x[1] > 0.5; });
  for (auto& x : P.x) x[1] -= 0.5 - floor;
}

/// What a drop at rest did.
struct DropRun {
  double mean_pressure = 0;    ///< over the fluid cells more than 3 dx inside the drop (Pa)
  double pressure_spread = 0;  ///< max - min over those cells (Pa)
  double laplace = 0;          ///< sigma / R in 2D, 2 sigma / R in 3D (Pa)
  double max_speed = 0;        ///< largest particle speed over the run (m/s)
  double late_speed = 0;       ///< largest particle speed over the run's last quarter (m/s)
  double capillary_speed = 0;  ///< sqrt(sigma / (rho R)), the scale of capillary flows (m/s)
  int steps = 0;
  double pressure_error() const { return mean_pressure / laplace - 1; }
};

/// Runs the drop at rest for `seconds`, then reads its pressure.
template <int Dim>
DropRun drop_at_rest(int cells_per_radius, double seconds, double sigma = 1, double mu = 0) {
  const slurry::Scene s = drop_scene<Dim>(cells_per_radius, sigma, mu);
  slurry::flip::FlipSolver<double, Dim> sim(s);
  DropRun r;
  r.laplace = (Dim - 1) * sigma / kDropRadius;
  r.capillary_speed = std::sqrt(sigma / (kDropDensity * kDropRadius));
  while (sim.time() < seconds - 1e-12) {
    sim.step(std::min(sim.stable_dt(), 0.05));
    r.max_speed = std::max(r.max_speed, double(sim.max_speed()));
    if (sim.time() > 0.75 * seconds) r.late_speed = std::max(r.late_speed, double(sim.max_speed()));
    ++r.steps;
  }
  const auto& g = sim.grid();
  const Eigen::Matrix<double, Dim, 1> centre = Eigen::Matrix<double, Dim, 1>::Constant(0.5);
  double sum = 0, lo = std::numeric_limits<double>::max(), hi = -lo;
  int n = 0;
  for (std::int64_t k = 0; k < g.num_cells(); ++k) {
    if (g.label[std::size_t(k)] != g.Fluid || (g.cell_center(g.cell_coord(k)) - centre).norm() > kDropRadius - 3 * g.dx)
      continue;
    const double p = g.pressure[std::size_t(k)];
    sum += p, lo = std::min(lo, p), hi = std::max(hi, p), ++n;
  }
  r.mean_pressure = n ? sum / n : 0;
  r.pressure_spread = n ? hi - lo : 0;
  return r;
}

/// What an oscillating drop did.
struct Oscillation {
  double period = 0;    ///< twice the mean time between zero crossings of the mode's moment (s)
  double rayleigh = 0;  ///< Rayleigh's period of mode 2 (s)
  int half_periods = 0; ///< intervals between zero crossings measured
  double m0 = 0;        ///< the moment at release (m^2)
  std::vector<double> peaks;  ///< the largest |m| between consecutive zero crossings, in order
  double farthest = 0;  ///< the farthest any particle came from the centre of mass, over R
};

/// The drop in the mode-2 shape of relative amplitude eps (an ellipse of semi-axes R (1 + eps)
/// along x and R / (1 + eps) in 2D; a prolate spheroid of R (1 + eps) along z and R / sqrt(1 + eps)
/// across in 3D: both of the disk's or ball's volume), cut from the same regular lattice of
/// particles (stretching the lattice instead would make its spacing differ between the axes, and
/// the surface's staircase with it, a mode-2 error as large as the signal), released at rest;
/// measures the period of the second moment m(t) = <x^2> - <y^2> (2D) or <z^2> - (<x^2> +
/// <y^2>) / 2 (3D) about the centre of mass over `half_periods` half periods, the amplitude of
/// each, and how far the particles stray from the centre. Rayleigh (1879,
/// "On the capillary phenomena of jets", Proc. R. Soc. London 29; Lamb, "Hydrodynamics",
/// sec. 275): omega^2 = n (n^2 - 1) sigma / (rho R^3) for a 2D drop and
/// n (n - 1) (n + 2) sigma / (rho R^3) for a 3D one, n = 2: 6 and 8.
template <int Dim>
Oscillation oscillating_drop(int cells_per_radius, double eps, int half_periods, double sigma = 1) {
  slurry::Scene s = drop_scene<Dim>(cells_per_radius, sigma);
  s.bodies[0].radius = kDropRadius * (1 + eps) + s.domain.dx;
  slurry::flip::FlipSolver<double, Dim> sim(s);
  using Vec = Eigen::Matrix<double, Dim, 1>;
  const Vec centre = Vec::Constant(0.5);
  Vec semi_axes = Vec::Constant(kDropRadius * (Dim == 3 ? 1 / std::sqrt(1 + eps) : 1 / (1 + eps)));
  semi_axes[Dim == 3 ? 2 : 0] = kDropRadius * (1 + eps);
  auto& P = sim.particles();
  keep_particles(P, [&](const Vec& x) { return (x - centre).cwiseQuotient(semi_axes).squaredNorm() <= 1; });
  Oscillation r;
  const auto moment = [&] {
    Vec mean = Vec::Zero();
    for (const auto& x : P.x) mean += x;
    mean /= double(P.size());
    Vec m2 = Vec::Zero();
    double far2 = 0;
    for (const auto& x : P.x) {
      const Vec d = (x - mean).cwiseAbs2();
      m2 += d;
      far2 = std::max(far2, d.sum());
    }
    m2 /= double(P.size());
    r.farthest = std::max(r.farthest, std::sqrt(far2) / kDropRadius);
    return Dim == 3 ? m2[2] - 0.5 * (m2[0] + m2[1]) : m2[0] - m2[1];
  };
  const double n = 2, factor = Dim == 3 ? n * (n - 1) * (n + 2) : n * (n * n - 1);
  r.rayleigh = 2 * M_PI / std::sqrt(factor * sigma / (kDropDensity * std::pow(kDropRadius, 3)));
  std::vector<double> crossings;
  double m_prev = moment(), t_prev = sim.time(), peak = 0;
  r.m0 = m_prev;
  while (int(crossings.size()) <= half_periods && sim.time() < (half_periods / 2 + 2) * r.rayleigh) {
    sim.step(std::min(sim.stable_dt(), 0.05));
    const double m = moment(), t = sim.time();
    if ((m_prev > 0) != (m > 0)) {
      crossings.push_back(t_prev + (t - t_prev) * m_prev / (m_prev - m));
      if (crossings.size() > 1) r.peaks.push_back(peak);
      peak = 0;
    }
    peak = std::max(peak, std::abs(m));
    m_prev = m, t_prev = t;
  }
  r.half_periods = int(crossings.size()) - 1;
  if (r.half_periods >= 1) r.period = 2 * (crossings.back() - crossings.front()) / r.half_periods;
  return r;
}

/// A puddle of glycerol (rho 1260 kg/m^3, mu 1.41 Pa s, sigma 0.0634 N/m at 20 C; CRC Handbook of
/// Chemistry and Physics) on the floor under gravity, 2D: a block 12 mm wide and 5 mm tall in a
/// tank 40 mm wide, APIC with the linear kernel, 8 particles per cell. Surface tension pulls the
/// block's corners round and gravity flattens it: a puddle much wider than the capillary length
/// l_c = sqrt(sigma / (rho g)) = 2.26 mm settles at the height 2 l_c sin(theta / 2), theta the
/// contact angle (de Gennes, Brochard-Wyart & Quere, "Capillarity and Wetting Phenomena", 2004,
/// ch. 2, on puddles), 3.20 mm for the 90 degrees at which the surface meets a wall (surface_tension.h).
struct Puddle {
  double height = 0;    ///< the liquid's mean height over the middle 4 mm of the puddle (m)
  double expected = 0;  ///< 2 l_c sin(45 degrees) (m)
  double width = 0;     ///< from the leftmost to the rightmost particle (m)
  double error() const { return height / expected - 1; }
};

/// The puddle after `seconds` on a grid of spacing dx (m). Its height is the particles' area
/// (dx^2 / 8 each, their rest density) within 2 mm of the puddle's middle, over 4 mm.
inline Puddle glycerol_puddle(double dx, double seconds) {
  constexpr double rho = 1260, mu = 1.41, sigma = 0.0634, g = 9.81;
  slurry::Scene s = drop_scene<2>(1, sigma, mu);  // APIC, linear kernel, double precision
  s.source = "puddle";
  s.solver.max_dt = 1.0 / 240;
  s.solver.gravity = {0, -g, 0};
  s.domain.max = Eigen::Vector3d(0.04, 0.01, 0);
  s.domain.dx = dx;
  s.materials[0].density = rho;
  slurry::BodyParams& b = s.bodies[0];
  b.shape = slurry::Shape::Box;
  b.min = Eigen::Vector3d(0.014, 0, 0);
  b.max = Eigen::Vector3d(0.026, 0.005, 0);
  b.particles_per_cell = 8;
  slurry::flip::FlipSolver<double, 2> sim(s);
  while (sim.time() < seconds - 1e-12) sim.step(std::min(sim.stable_dt(), seconds - sim.time()));
  const auto& x = sim.particles().x;
  double lo = x.front()[0], hi = lo;
  for (const auto& p : x) lo = std::min(lo, p[0]), hi = std::max(hi, p[0]);
  const double middle = 0.5 * (lo + hi), half = 0.002;
  std::size_t n = 0;
  for (const auto& p : x) n += std::abs(p[0] - middle) < half;
  Puddle r;
  r.height = double(n) * dx * dx / 8 / (2 * half);
  r.expected = 2 * std::sqrt(sigma / (rho * g)) * std::sin(M_PI / 4);
  r.width = hi - lo;
  return r;
}

}  // namespace slurry_test
