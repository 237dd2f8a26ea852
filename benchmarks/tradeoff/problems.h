#pragma once
// The reference problems of the speed-against-accuracy study (benchmarks/tradeoff/README.md):
// each builds a scene at a grid spacing dx and measures one error against an analytic solution
// or a published experiment. A run returns the error, a signed value (for the self-convergence
// in dt), an auxiliary figure and the work done (particle-steps, bytes held).
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/scene/quality.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace tradeoff {

using slurry::Scene;

struct Result {
  double error = NAN;           ///< the problem's error measure (>= 0)
  double value = NAN;           ///< the signed quantity behind it (for self-convergence in dt)
  double aux = NAN;             ///< a second figure (e.g. spurious speed), NAN if none
  double particle_steps = 0;    ///< sum over substeps of the particle count
  double sim_bytes = 0;         ///< MpmSolver::bytes() at the end (particles and grid)
  double substeps = 0;
};

struct Problem {
  std::string name;        ///< e.g. "bar_2d"
  std::string what;        ///< one line: the problem and its error measure
  std::string reference;   ///< the analytic solution or experiment, cited
  std::string error_name;  ///< column meaning of `error`
  std::string aux_name;    ///< meaning of `aux`, empty if none
  std::vector<double> dx_levels;  ///< coarse to fine; the middle one is the study's default
  std::vector<double> dx_reduced; ///< the levels of the reduced (ctest) study
  std::function<Scene(double dx)> scene;
  std::function<Result(const Scene&)> run;
  bool flip = false;       ///< FLIP liquid (else MPM)
  bool solid = false;      ///< implicit integration applies (MPM solids)
  bool has_affine_init = false;
  /// The smallest difference of errors the measure resolves (0: limited by round-off only);
  /// presets are compared within the larger of it and the measured spread.
  double resolution = 0;
};

// ---------------------------------------------------------------------------------------------
// Scene helpers

inline Scene base_scene(int dim, slurry::SolverType type, const Eigen::Vector3d& max, double dx) {
  Scene s;
  s.source = "tradeoff";
  s.solver.type = type;
  s.solver.dimension = dim;
  slurry::apply_default_quality(s);  // the library defaults, as a scene file without solver.quality
  s.domain.min = {0, 0, 0};
  s.domain.max = max;
  s.domain.dx = dx;
  return s;
}

inline slurry::MaterialParams material(const char* name, slurry::ElasticModel model, double rho) {
  slurry::MaterialParams m;
  m.name = name;
  m.model = model;
  m.density = rho;
  return m;
}

inline slurry::BodyParams box(const char* material, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  slurry::BodyParams b;
  b.shape = slurry::Shape::Box;
  b.material = material;
  b.min = lo;
  b.max = hi;
  return b;
}

template <class Sim>
double particle_steps(const Sim& sim) {
  return double(sim.steps()) * double(sim.particle_count());
}

// ---------------------------------------------------------------------------------------------
// 1. Elastic bar, first axial mode (MPM 2D). A free-free bar of length L, nu = 0, so the
// uniaxial wave speed is c = sqrt(E / rho); started with v0 cos(pi x / L), its first mode has
// period T = 2 L / c (Sulsky, Zhou & Schreyer 1995, "Application of a particle-in-cell method to
// solid mechanics", sec. 4, the vibrating bar; free-free variant). Error |T_measured / T - 1|
// from the zero crossings of the left quarter's mean velocity over 2.6 periods.

inline Scene bar_scene(double dx) {
  Scene s = base_scene(2, slurry::SolverType::MPM, {2, 0.5, 0}, dx);
  s.solver.gravity = {0, 0, 0};
  auto m = material("bar", slurry::ElasticModel::FixedCorotated, 1);
  m.E = 1e4;
  m.nu = 0;
  s.materials = {m};
  s.bodies = {box("bar", {0.5, 0.1875, 0}, {1.5, 0.3125, 0})};
  return s;
}

constexpr double kBarLength = 1.0, kBarSpeed = 0.05;  ///< the bar's length (m), its mode's amplitude (m/s)

/// The bar's first axial mode at rest strain: v = v0 cos(pi (x - 0.5) / L).
template <class T>
void bar_initial_velocity(slurry::MpmSolver<T, 2>& sim) {
  auto& P = sim.particles();
  for (std::size_t p = 0; p < P.size(); ++p)
    P.v[p] = Eigen::Matrix<T, 2, 1>(T(kBarSpeed * std::cos(M_PI * (double(P.x[p][0]) - 0.5) / kBarLength)), T(0));
}

template <class T>
Result bar_run_t(const Scene& s) {
  slurry::MpmSolver<T, 2> sim(s);
  const double E = s.materials[0].E, rho = s.materials[0].density;
  const double L = kBarLength, c = std::sqrt(E / rho), period = 2 * L / c;
  bar_initial_velocity(sim);
  auto& P = sim.particles();
  auto left_velocity = [&] {
    double sum = 0, n = 0;
    for (std::size_t p = 0; p < P.size(); ++p)
      if (P.x[p][0] < 0.75) sum += double(P.v[p][0]), n += 1;
    return sum / n;
  };
  std::vector<double> crossings;
  double prev = left_velocity(), t_prev = 0;
  while (sim.time() < 2.6 * period) {
    const double dt = double(sim.stable_dt());
    sim.step(T(dt));
    const double v = left_velocity();
    if ((prev > 0) != (v > 0)) crossings.push_back(t_prev + dt * prev / (prev - v));
    prev = v;
    t_prev = sim.time();
  }
  Result r;
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  if (crossings.size() < 4) return r;
  const double measured = 2 * (crossings.back() - crossings.front()) / double(crossings.size() - 1);
  r.value = measured / period;
  r.error = std::abs(r.value - 1);
  return r;
}

// ---------------------------------------------------------------------------------------------
// 2. Two elastic disks colliding (Sulsky, Chen & Schreyer 1994, "A particle method for
// history-dependent materials", CMAME 118, sec. 5: unit square, disks of radius 0.2 at (0.25,
// 0.25) and (0.75, 0.75) moving at +-(0.1, 0.1), E = 1000 Pa, nu = 0.3, rho = 1000). The exact
// collision is elastic: total energy is conserved. Error: energy lost at t = 3 s, 1 - E(3)/E(0).

inline Scene disks_scene(double dx) {
  Scene s = base_scene(2, slurry::SolverType::MPM, {1, 1, 0}, dx);
  s.solver.gravity = {0, 0, 0};
  auto m = material("disk", slurry::ElasticModel::CorotatedLinear, 1000);
  m.E = 1000;
  m.nu = 0.3;
  s.materials = {m};
  slurry::BodyParams a;
  a.shape = slurry::Shape::Sphere;
  a.material = "disk";
  a.center = {0.25, 0.25, 0};
  a.radius = 0.2;
  a.velocity = {0.1, 0.1, 0};
  slurry::BodyParams b = a;
  b.center = {0.75, 0.75, 0};
  b.velocity = {-0.1, -0.1, 0};
  s.bodies = {a, b};
  return s;
}

template <class T>
Result disks_run_t(const Scene& s) {
  slurry::MpmSolver<T, 2> sim(s);
  const double e0 = double(sim.kinetic_energy() + sim.elastic_energy());
  sim.advance_to(3.0);
  Result r;
  r.value = 1 - double(sim.kinetic_energy() + sim.elastic_energy()) / e0;
  r.error = std::abs(r.value);
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  return r;
}

// ---------------------------------------------------------------------------------------------
// 3. Granular column collapse (MPM). 2D (plane strain): a rectangular column of length d_i and
// height h_i against the left wall, released onto a rough floor; Lube, Huppert, Sparks & Freundt
// 2005, "Collapses of two-dimensional granular columns", Phys. Rev. E 72, 041301: runout
// (d_inf - d_i) / d_i = 1.2 a for a = h_i / d_i below about 2.3. 3D: the axisymmetric squat
// column of tests/mpm/granular_validation_test.cpp against Lube, Huppert, Sparks &
// Hallworth 2004, J. Fluid Mech. 508: (r_inf - r_i) / r_i = 1.24 a for a < 1.7. The sand is that
// of examples/scenes/sand_column_3d.json (Drucker-Prager, 30 degrees; Klar et al. 2016). Error
// |runout / published - 1| at t = 1 s (the deposit has stopped), runout measured as the
// 99.5th percentile of the particles' distance plus half a particle spacing.

inline slurry::MaterialParams sand() {
  auto m = material("sand", slurry::ElasticModel::HenckyStVK, 2200);
  m.E = 3.5e5;
  m.nu = 0.3;
  m.plasticity = slurry::PlasticModel::DruckerPrager;
  m.friction_angle = 30;
  return m;
}

constexpr double kColumnLength = 0.15, kColumnHeight = 0.15;  // 2D, a = 1

inline Scene granular2d_scene(double dx) {
  Scene s = base_scene(2, slurry::SolverType::MPM, {0.6, 0.3, 0}, dx);
  s.materials = {sand()};
  const double wall = 2 * dx;  // boundaries.thickness cells
  s.bodies = {box("sand", {wall, wall, 0}, {wall + kColumnLength, wall + kColumnHeight, 0})};
  s.boundaries.walls = slurry::Condition::Separate;
  s.boundaries.friction = 0.5;
  return s;
}

constexpr double kRi = 0.15, kHi = 0.075;  // 3D squat column, a = 0.5

inline Scene granular3d_scene(double dx) {
  Scene s = base_scene(3, slurry::SolverType::MPM, {1, 0.4, 1}, dx);
  s.materials = {sand()};
  slurry::BodyParams b;
  b.shape = slurry::Shape::Cylinder;
  b.material = "sand";
  b.center = {0.5, 2 * dx + 0.5 * kHi, 0.5};
  b.radius = kRi;
  b.height = kHi;
  b.axis = 1;
  s.bodies = {b};
  s.boundaries.walls = slurry::Condition::Separate;
  s.boundaries.friction = 0.5;
  return s;
}

template <class T, int Dim>
Result granular_run_t(const Scene& s) {
  slurry::MpmSolver<T, Dim> sim(s);
  sim.advance_to(1.0);
  const auto& P = sim.particles();
  const double dx = s.domain.dx, ppc = s.bodies[0].particles_per_cell;
  const double spacing = dx / std::pow(ppc, 1.0 / Dim);
  std::vector<double> d(P.size());
  for (std::size_t p = 0; p < P.size(); ++p)
    d[p] = Dim == 2 ? double(P.x[p][0]) - 2 * dx : std::hypot(double(P.x[p][0]) - 0.5, double(P.x[p][Dim - 1]) - 0.5);
  const std::size_t k = std::size_t(0.995 * double(d.size()));
  std::nth_element(d.begin(), d.begin() + std::ptrdiff_t(k), d.end());
  const double runout = d[k] + 0.5 * spacing;
  const double expected = Dim == 2 ? kColumnLength * (1 + 1.2 * kColumnHeight / kColumnLength)
                                   : kRi * (1 + 1.24 * kHi / kRi);
  Result r;
  r.value = runout / expected;
  r.error = std::abs(r.value - 1);
  r.aux = 0;  // the largest particle speed: the deposit has stopped
  for (const auto& v : P.v) r.aux = std::max(r.aux, double(v.norm()));
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  return r;
}

// ---------------------------------------------------------------------------------------------
// FLIP liquids

inline Scene liquid_scene(int dim, const Eigen::Vector3d& max, double dx) {
  Scene s = base_scene(dim, slurry::SolverType::FLIP, max, dx);
  if (dim == 3) s.solver.gravity = {0, -9.81, 0};
  s.materials = {material("water", slurry::ElasticModel::Fluid, 1000)};
  return s;
}

// 4. Hydrostatic column: a pool of depth H at rest for 1 s. Exact: u = 0, p = rho g (H - y).
// Error: largest pressure error over the fluid cells below the top row (away from the side
// walls) relative to the bottom pressure rho g H (a max norm; relative to the local pressure
// the cell below the surface keeps the same first-order relative error at every dx); aux: the
// largest particle speed seen (spurious velocity, m/s).
inline Scene hydrostatic_scene(int dim, double dx) {
  Scene s = liquid_scene(dim, dim == 2 ? Eigen::Vector3d(1, 1, 0) : Eigen::Vector3d(0.5, 0.5, 0.5), dx);
  const double H = dim == 2 ? 0.5 : 0.25;
  s.bodies = {box("water", {0, 0, 0}, dim == 2 ? Eigen::Vector3d(1, H, 0) : Eigen::Vector3d(0.5, H, 0.5))};
  return s;
}

template <class T, int Dim>
Result hydrostatic_run_t(const Scene& s) {
  slurry::flip::FlipSolver<T, Dim> sim(s);
  const double H = s.bodies[0].max[1], g = 9.81, rho = 1000, dx = s.domain.dx;
  double worst_speed = 0;
  for (int f = 1; f <= 24; ++f) {
    sim.advance_to(f / 24.0);
    worst_speed = std::max(worst_speed, double(sim.max_speed()));
  }
  const auto& grid = sim.grid();
  double worst = 0;
  const int rows = int(std::lround(H / dx)) - 1;
  for (std::int64_t k = 0; k < grid.num_cells(); ++k) {
    const auto i = grid.cell_coord(k);
    if (i[1] >= rows) continue;
    bool interior = true;
    for (int d = 0; d < Dim; ++d)
      if (d != 1 && (i[d] < 2 || i[d] >= grid.res[d] - 2)) interior = false;
    if (!interior) continue;
    const double y = double(grid.cell_center(i)[1]);
    const double exact = rho * g * (H - y);
    const double p = grid.label[k] == std::decay_t<decltype(grid)>::Fluid ? double(grid.pressure[k]) : 0.0;
    worst = std::max(worst, std::abs(p - exact) / (rho * g * H));
  }
  Result r;
  r.error = worst;
  r.value = worst;
  r.aux = worst_speed;
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  return r;
}

// 5. Standing wave: mode k = pi / L in a tank of length L = 1 m and depth h = 0.5 m, linear
// theory omega^2 = g k tanh(k h) (Lamb, Hydrodynamics, 6th ed., sec. 228). Started flat with
// the mode's linear velocity field (amplitude 1 cm); error |T_measured / T - 1| from the zero
// crossings of the horizontal centre of mass over 2.8 periods.
inline Scene wave_scene(double dx) {
  Scene s = liquid_scene(2, {1, 1, 0}, dx);
  s.bodies = {box("water", {0, 0, 0}, {1, 0.5, 0})};
  return s;
}

constexpr double kWaveLength = 1, kWaveDepth = 0.5, kWaveAmplitude = 0.01;  ///< L, h (m), amplitude (m)

/// omega^2 = g k tanh(k h) of the standing wave's first mode, k = pi / L.
inline double wave_omega() {
  const double k = M_PI / kWaveLength;
  return std::sqrt(9.81 * k * std::tanh(k * kWaveDepth));
}

/// The first mode's velocity at its surface's rest: phi = (a / k) cos(k x) cosh(k y),
/// u = -a sin(kx) cosh(ky), v = a cos(kx) sinh(ky), and the affine vectors its gradient.
template <class T>
void wave_initial_velocity(slurry::flip::FlipSolver<T, 2>& sim) {
  const double k = M_PI / kWaveLength, a = kWaveAmplitude * wave_omega() / std::sinh(k * kWaveDepth);
  auto& P = sim.particles();
  for (std::size_t p = 0; p < P.size(); ++p) {
    const double x = double(P.x[p][0]), y = double(P.x[p][1]);
    P.v[p] = {T(-a * std::sin(k * x) * std::cosh(k * y)), T(a * std::cos(k * x) * std::sinh(k * y))};
    if (P.affine) {
      P.c[0][p] = {T(-a * k * std::cos(k * x) * std::cosh(k * y)), T(-a * k * std::sin(k * x) * std::sinh(k * y))};
      P.c[1][p] = {T(-a * k * std::sin(k * x) * std::sinh(k * y)), T(a * k * std::cos(k * x) * std::cosh(k * y))};
    }
  }
}

template <class T>
Result wave_run_t(const Scene& s) {
  slurry::flip::FlipSolver<T, 2> sim(s);
  const double period = 2 * M_PI / wave_omega();
  wave_initial_velocity(sim);
  auto x_cm = [&] {
    double sum = 0;
    for (const auto& x : sim.particles().x) sum += double(x[0]);
    return sum / double(sim.particles().size());
  };
  const double x0 = x_cm();
  std::vector<double> crossings;
  double prev = 0, t_prev = 0;
  while (sim.time() < 2.8 * period) {
    const double dt = double(sim.stable_dt());
    sim.step(T(dt));
    const double d = x_cm() - x0;
    if (t_prev > 0.25 * period && (prev > 0) != (d > 0)) crossings.push_back(t_prev + dt * prev / (prev - d));
    prev = d;
    t_prev = sim.time();
  }
  Result r;
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  if (crossings.size() < 3) return r;
  const double measured = 2 * (crossings.back() - crossings.front()) / double(crossings.size() - 1);
  r.value = measured / period;
  r.error = std::abs(r.value - 1);
  return r;
}

// 6. Taylor-Green vortex in the closed unit box, u = sin(pi x) cos(pi y), v = -cos(pi x)
// sin(pi y) (it satisfies no-penetration at the walls; Taylor & Green 1937), inviscid, no
// gravity: the exact flow is steady and keeps its kinetic energy. Error: the fraction of kinetic
// energy lost after 1 s (numerical dissipation; Jiang et al. 2015, sec. 8).
inline Scene taylor_green_scene(double dx) {
  Scene s = liquid_scene(2, {1, 1, 0}, dx);
  s.solver.gravity = {0, 0, 0};
  s.bodies = {box("water", {0, 0, 0}, {1, 1, 0})};
  return s;
}

/// The vortex's velocity and, with APIC, its gradient as the affine vectors.
template <class T>
void taylor_green_initial_velocity(slurry::flip::FlipSolver<T, 2>& sim) {
  auto& P = sim.particles();
  for (std::size_t p = 0; p < P.size(); ++p) {
    const double x = double(P.x[p][0]), y = double(P.x[p][1]);
    P.v[p] = {T(std::sin(M_PI * x) * std::cos(M_PI * y)), T(-std::cos(M_PI * x) * std::sin(M_PI * y))};
    if (P.affine) {
      P.c[0][p] = {T(M_PI * std::cos(M_PI * x) * std::cos(M_PI * y)), T(-M_PI * std::sin(M_PI * x) * std::sin(M_PI * y))};
      P.c[1][p] = {T(M_PI * std::sin(M_PI * x) * std::sin(M_PI * y)), T(-M_PI * std::cos(M_PI * x) * std::cos(M_PI * y))};
    }
  }
}

template <class T>
Result taylor_green_run_t(const Scene& s) {
  slurry::flip::FlipSolver<T, 2> sim(s);
  taylor_green_initial_velocity(sim);
  const double e0 = double(sim.kinetic_energy());
  sim.advance_to(1.0);
  Result r;
  r.value = 1 - double(sim.kinetic_energy()) / e0;
  r.error = std::abs(r.value);
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  return r;
}

// 7. Dam break against Martin & Moyce 1952 ("Part IV. An experimental study of the collapse of
// liquid columns on a rigid horizontal plane", Phil. Trans. R. Soc. Lond. A 244, 312-324): a
// column of width a and height 2a (n^2 = 2) released at the left wall; surge front Z = x / a
// against T = t sqrt(2 g / a). The points are the commonly quoted tabulation of their n^2 = 2,
// a = 2.25 in series (as used, e.g., by the Lethe project's dam-break example, which cites the
// paper's tables 2 and 6); they were not checked against the paper itself. The front is the
// 99.9th percentile of the particles' x plus half a particle spacing.
//
// The experiment's clock started with the release of a gate (a membrane burst, in their set-up)
// that did not free the column at once: the measured front lags an instantaneous release by a
// delay the paper does not report. The error therefore compares the simulated front, shifted
// later in time by the delay tau that fits it best, with the measured one: tau in [0, 0.6] (in
// units of T; 0.6 is 0.061 s at a = 0.2 m) minimising the mean of |Z_sim(T_i - tau) / Z_i - 1|
// over the points, the front sampled every 0.025 in T and interpolated linearly (Z = 1 before
// T = 0). Error: that minimum; `value` and `aux`: tau. A solver whose front runs too fast or too
// slow keeps its error, since one delay cannot fit the front's speed at every T; the delay
// removes only the start-up that the experiment and an instantaneous release do not share.
constexpr double kDamA = 0.2;
constexpr double kMartinMoyceT[] = {0.41, 0.84, 1.19, 1.43, 1.63, 1.83, 1.98, 2.20,
                                    2.32, 2.51, 2.65, 2.83, 2.98, 3.11, 3.33};
constexpr double kMartinMoyceZ[] = {1.11, 1.22, 1.44, 1.67, 1.89, 2.11, 2.33, 2.56,
                                    2.78, 3.00, 3.22, 3.44, 3.67, 3.89, 4.11};
constexpr double kDamSampleT = 0.025;  ///< front sampling interval, units of T
constexpr double kDamMaxDelay = 0.6;   ///< largest gate delay fitted, units of T

inline Scene dam_break_scene(double dx) {
  Scene s = liquid_scene(2, {5 * kDamA, 2.5 * kDamA, 0}, dx);
  s.bodies = {box("water", {0, 0, 0}, {kDamA, 2 * kDamA, 0})};
  return s;
}

/// The mean relative front error against Martin & Moyce of a front `z` sampled every
/// kDamSampleT from T = 0, the simulation delayed by `tau`.
inline double dam_break_deviation(const std::vector<double>& z, double tau) {
  double sum = 0;
  const int n = int(std::size(kMartinMoyceT));
  for (int i = 0; i < n; ++i) {
    const double T = kMartinMoyceT[i] - tau;
    double zs = 1;
    if (T > 0) {
      const double u = T / kDamSampleT;
      const std::size_t k = std::min(std::size_t(u), z.size() - 2);
      zs = z[k] + (u - double(k)) * (z[k + 1] - z[k]);
    }
    sum += std::abs(zs / kMartinMoyceZ[i] - 1);
  }
  return sum / n;
}

template <class T>
Result dam_break_run_t(const Scene& s) {
  slurry::flip::FlipSolver<T, 2> sim(s);
  const double g = 9.81, spacing = s.domain.dx / std::sqrt(s.bodies[0].particles_per_cell);
  const double t_unit = 1 / std::sqrt(2 * g / kDamA);
  const int samples = int(std::ceil(kMartinMoyceT[std::size(kMartinMoyceT) - 1] / kDamSampleT)) + 2;
  std::vector<double> z;  // the front, Z, every kDamSampleT from T = 0
  for (int i = 0; i < samples; ++i) {
    if (i > 0) sim.advance_to(i * kDamSampleT * t_unit);
    std::vector<double> x;
    x.reserve(sim.particle_count());
    for (const auto& p : sim.particles().x) x.push_back(double(p[0]));
    const std::size_t k = std::size_t(0.999 * double(x.size()));
    std::nth_element(x.begin(), x.begin() + std::ptrdiff_t(k), x.end());
    z.push_back((x[k] + 0.5 * spacing) / kDamA);
  }
  Result r;
  r.error = std::numeric_limits<double>::infinity();
  for (double tau = 0; tau <= kDamMaxDelay + 1e-12; tau += 0.001)
    if (const double e = dam_break_deviation(z, tau); e < r.error) r.error = e, r.value = tau;
  r.aux = r.value;
  r.particle_steps = particle_steps(sim);
  r.substeps = double(sim.steps());
  r.sim_bytes = double(sim.bytes());
  return r;
}

}  // namespace tradeoff
