// Viscosity of the FLIP liquid (viscosity.h, Batty & Bridson 2008): plane Poiseuille flow in 2D
// and the flow through a square duct in 3D against their analytic profiles, free-slip walls
// without shear, a very viscous column that spreads without blowing up or losing volume, and
// the scene key's bad values. (The standing wave's damping against Lamb is in
// viscosity_wave_test.cpp.)
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/flip/viscosity.h"
#include "slurry/engine/scene/scene.h"
#include "liquid_scene.h"
#include "slurry/io/scene_file.h"

namespace {

using slurry::Scene;

/// A MacGrid of `res` cells of size dx filled with liquid (every cell Fluid, phi = -dx/2).
template <int Dim>
slurry::flip::MacGrid<double, Dim> full_grid(const Eigen::Matrix<int, Dim, 1>& res, double dx) {
  slurry::flip::MacGrid<double, Dim> g;
  g.resize(res, dx, Eigen::Matrix<double, Dim, 1>::Zero(), false);
  std::fill(g.label.begin(), g.label.end(), std::uint8_t(slurry::flip::MacGrid<double, Dim>::Fluid));
  std::fill(g.phi.begin(), g.phi.end(), -0.5 * dx);
  return g;
}

/// Drives the liquid of g along x with the body force `accel` (m/s^2) through implicit viscous
/// steps of length dt (each much longer than the viscous time H^2 / nu), to the steady state.
template <int Dim>
void drive_to_steady_state(slurry::flip::MacGrid<double, Dim>& g, double accel, double nu, double dt, int steps) {
  const double rho = 1000;
  slurry::flip::ViscositySolver<double, Dim> visc;
  visc.tolerance = 1e-10;
  for (int s = 0; s < steps; ++s) {
    for (auto& u : g.u[0]) u += dt * accel;
    const auto rep = visc.solve(g, dt, rho, nu * rho);
    ASSERT_TRUE(rep.converged) << "step " << s << ": residual " << rep.relative_residual;
  }
}

// Plane Poiseuille flow (e.g. Batchelor, "An introduction to fluid dynamics", sec. 4.2): a body
// force g along the channel between no-slip walls at y = 0 and y = H drives the steady profile
// u(y) = g / (2 nu) y (H - y). The channel is 6 H long with closed ends; its middle is 3 H from
// them, where their disturbance has decayed (as exp(-pi x / H)).
TEST(FlipViscosity, PlanePoiseuille2D) {
  const int ny = 16, nx = 6 * ny;
  const double H = 1, dx = H / ny, nu = 1, accel = 1;
  auto g = full_grid<2>(Eigen::Vector2i(nx, ny), dx);
  drive_to_steady_state<2>(g, accel, nu, 10 * H * H / nu, 12);
  const double centre = accel / (2 * nu) * (H / 2) * (H / 2);
  double worst = 0;
  for (int j = 0; j < ny; ++j) {
    const double y = (j + 0.5) * dx, exact = accel / (2 * nu) * y * (H - y);
    const double u = g.u[0][std::size_t(g.face(0, Eigen::Vector2i(nx / 2, j)))];
    worst = std::max(worst, std::abs(u - exact) / centre);
  }
  std::printf("[ figure ] plane Poiseuille 2D, H = %d cells: max |u - u_exact| / u_centre = %.4f%% (centre %.5f m/s)\n", ny,
              100 * worst, centre);
  EXPECT_LT(worst, 0.02);
}

/// Steady flow through the duct |y| < a, |z| < b under the body force g along x, no slip on its
/// walls (White, "Viscous Fluid Flow", 3rd ed., eq. 3-48, with -dp/dx = rho g).
double duct_velocity(double y, double z, double a, double b, double accel, double nu) {
  double sum = 0;
  for (int i = 1; i < 200; i += 2) {
    const double k = i * M_PI / (2 * a);
    sum += (((i - 1) / 2) % 2 ? -1.0 : 1.0) * (1 - std::cosh(k * z) / std::cosh(k * b)) * std::cos(k * y) / (i * i * i);
  }
  return 16 * a * a * accel / (nu * M_PI * M_PI * M_PI) * sum;
}

// The 3D counterpart: a square duct, no-slip on all four walls, against its series solution.
TEST(FlipViscosity, SquareDuctPoiseuille3D) {
  const int n = 16, nx = 3 * n;
  const double H = 1, dx = H / n, nu = 1, accel = 1;
  auto g = full_grid<3>(Eigen::Vector3i(nx, n, n), dx);
  drive_to_steady_state<3>(g, accel, nu, 10 * H * H / nu, 12);
  const double a = H / 2, centre = duct_velocity(0, 0, a, a, accel, nu);
  double worst = 0;
  for (int j = 0; j < n; ++j)
    for (int k = 0; k < n; ++k) {
      const double y = (j + 0.5) * dx - a, z = (k + 0.5) * dx - a;
      const double u = g.u[0][std::size_t(g.face(0, Eigen::Vector3i(nx / 2, j, k)))];
      worst = std::max(worst, std::abs(u - duct_velocity(y, z, a, a, accel, nu)) / centre);
    }
  std::printf("[ figure ] square duct 3D, %d x %d cells: max |u - u_exact| / u_centre = %.4f%% (centre %.5f m/s)\n", n, n,
              100 * worst, centre);
  EXPECT_LT(worst, 0.02);
}

// Free-slip walls exert no shear: a velocity v = 0.3 m/s along the x walls (closed floor and
// ceiling, which stop it there) stays uniform across the channel, every column the same as the
// middle one; no-slip walls hold the columns next to them back.
TEST(FlipViscosity, FreeSlipWallsExertNoShear) {
  const int n = 8;
  const double dx = 1.0 / n;
  auto g = full_grid<2>(Eigen::Vector2i(n, n), dx);
  for (std::int64_t f = 0; f < g.num_faces(1); ++f) {
    const auto i = g.face_coord(1, f);
    g.u[1][std::size_t(f)] = i[1] > 0 && i[1] < n ? 0.3 : 0.0;
  }
  slurry::flip::ViscositySolver<double, 2> visc;
  visc.no_slip_walls = false;
  visc.tolerance = 1e-12;
  auto h = g;
  visc.solve(g, 0.01, 1000, 100.0);  // nu dt / dx^2 = 0.064
  slurry::flip::ViscositySolver<double, 2> sticky;
  sticky.tolerance = 1e-12;
  sticky.solve(h, 0.01, 1000, 100.0);
  const int mid = n / 2;
  const double free_wall = g.u[1][std::size_t(g.face(1, Eigen::Vector2i(0, mid)))];
  const double free_mid = g.u[1][std::size_t(g.face(1, Eigen::Vector2i(mid, mid)))];
  const double stuck_wall = h.u[1][std::size_t(h.face(1, Eigen::Vector2i(0, mid)))];
  std::printf("[ figure ] uniform v = 0.3 m/s: at the x wall %.6f (free slip), %.6f (no slip); mid-channel %.6f\n", free_wall,
              stuck_wall, free_mid);
  EXPECT_NEAR(free_wall, free_mid, 1e-9) << "free-slip walls exert no shear";
  EXPECT_LT(stuck_wall, 0.95 * free_wall) << "no-slip walls hold the liquid back";
}

/// A 2D double-precision FLIP scene over [0, w] x [0, h] with one liquid of viscosity mu.
Scene viscous_scene(double w, double h, double dx, double mu) {
  return slurry_test::liquid_scene(w, h, dx, slurry::TransferKind::APIC, 1.0 / 240, "liquid", mu);
}

slurry::BodyParams box(double x0, double y0, double x1, double y1, double ppc = 4) {
  return slurry_test::liquid_box(x0, y0, x1, y1, "liquid", ppc);
}

// A very viscous column (mu = 1000 Pa s, nu = 1 m^2/s: a thick tar at the 1 m scale, its
// viscous time H^2 / nu 0.16 s far longer than a step) slumps under gravity: it spreads, far
// slower than water, without blowing up (speeds under the free fall's), and keeps its volume.
TEST(FlipViscosity, ViscousColumnSpreadsAndKeepsVolume) {
  const double dx = 1.0 / 40;
  const auto run = [&](double mu, double& front, double& max_speed, double& drift) {
    Scene s = viscous_scene(2, 1, dx, mu);
    s.solver.cfl = 3;
    s.solver.max_dt = 1.0 / 60;
    s.bodies = {box(0, 0, 0.2, 0.4)};
    slurry::flip::FlipSolver<double, 2> sim(s);
    const double v0 = sim.take_stats().volume;
    max_speed = 0;
    drift = 0;
    for (int f = 1; f <= 60; ++f) {  // 1 s
      sim.advance_to(f / 60.0);
      max_speed = std::max(max_speed, double(sim.max_speed()));
      drift = std::max(drift, std::abs(sim.take_stats().volume / v0 - 1));
    }
    front = 0;
    for (const auto& x : sim.particles().x) front = std::max(front, x[0]);
  };
  double front_visc, speed_visc, drift_visc, front_water, speed_water, drift_water;
  run(1000, front_visc, speed_visc, drift_visc);
  run(0, front_water, speed_water, drift_water);
  // (The inviscid run's volume is not compared: it ends as a sheet one or two cells thin, which
  // the stats' measure, calibrated on interior cells, does not see.)
  std::printf("[ figure ] column 0.2 x 0.4 m after 1 s: front at %.3f m (mu = 1000 Pa s) vs %.3f m (inviscid); max speed %.3f vs "
              "%.3f m/s; volume drift %.2f%%\n",
              front_visc, front_water, speed_visc, speed_water, 100 * drift_visc);
  EXPECT_GT(front_visc, 0.25) << "the column spreads";
  EXPECT_LT(front_visc, 0.5 * front_water) << "far slower than water";
  EXPECT_LT(speed_visc, std::sqrt(2 * 9.81 * 0.4)) << "no blow-up: slower than a free fall from the column's top";
  EXPECT_LT(drift_visc, 0.05) << "volume kept";
}

// The scene key: a negative or missing-range viscosity is refused naming the key; on an MPM
// material it is an unknown key, as every key of another solver.
TEST(FlipViscosity, BadViscosityIsRefusedNamingTheKey) {
  const auto scene = slurry_test::material_scene_text;
  const auto message = slurry_test::scene_error;
  const std::string flip = R"({"type": "flip", "dimension": 2})";
  EXPECT_NE(message(scene(flip, R"({"name": "a", "model": "fluid", "viscosity": -1})"))
                .find("materials[0].viscosity: expected a finite number >= 0, got -1"),
            std::string::npos);
  EXPECT_NE(message(scene(flip, R"({"name": "a", "model": "fluid", "viscosity": "thick"})")).find("materials[0].viscosity"),
            std::string::npos);
  EXPECT_NE(message(scene(R"({"type": "mpm", "dimension": 2})", R"({"name": "a", "model": "fluid", "viscosity": 1})"))
                .find("materials[0].viscosity: unknown key"),
            std::string::npos);
  // A scene built in code gets the same checks (infinite or NaN values cannot come from JSON).
  Scene s = viscous_scene(1, 1, 0.05, std::numeric_limits<double>::infinity());
  s.bodies = {box(0, 0, 1, 0.4)};
  try {
    s.validate();
    ADD_FAILURE() << "accepted an infinite viscosity";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("materials[0].viscosity: expected a finite number >= 0, got inf"), std::string::npos)
        << e.what();
  }
  Scene m = viscous_scene(1, 1, 0.05, 2);
  m.solver.type = slurry::SolverType::MPM;
  m.bodies = {box(0, 0, 1, 0.4)};
  try {
    m.validate();
    ADD_FAILURE() << "accepted a viscosity on an MPM material";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("materials[0].viscosity"), std::string::npos) << e.what();
  }
  EXPECT_EQ(message(scene(flip, R"({"name": "a", "model": "fluid", "viscosity": 2.5})")), "accepted");
  EXPECT_DOUBLE_EQ(slurry::parse_scene(scene(flip, R"({"name": "a", "model": "fluid", "viscosity": 2.5})"), "ok.json")
                       .materials[0]
                       .viscosity,
                   2.5);
}

}  // namespace
