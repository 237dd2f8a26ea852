// Surface tension of the FLIP liquid (surface_tension.h, ghost-fluid pressure jump): the pressure
// inside a drop at rest against Laplace's sigma / R (2D) and 2 sigma / R (3D), the spurious
// currents around it, the period of a drop's mode-2 oscillation against Rayleigh's, the
// capillary time step limit, and the scene key's bad values. The sizes here are CI's; the
// same checks at finer grids carry the label `validation` (surface_tension_validation_test.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/transfer/parallel.h"
#include "liquid_scene.h"
#include "slurry/io/scene_file.h"
#include "surface_tension_drop.h"

namespace {

using slurry::Scene;
using slurry_test::DropRun;

/// Prints and checks a drop at rest: its pressure within 5% of Laplace's; its largest speed, the
/// relaxation of the seeding's staircase through capillary waves (undamped without viscosity),
/// bounded: 0.12 (2D) and 0.15 (3D) of the capillary speed measured, not growing.
void check_drop_at_rest(const DropRun& r, const char* what) {
  std::printf("[ figure ] %s: mean pressure inside %.5f Pa, Laplace %.5f Pa, error %.3f%%; pressure spread (max - min) "
              "%.3f%%; largest speed %.3g m/s = %.3g of sqrt(sigma / (rho R)); %d steps\n",
              what, r.mean_pressure, r.laplace, 100 * r.pressure_error(), 100 * r.pressure_spread / r.laplace, r.max_speed,
              r.max_speed / r.capillary_speed, r.steps);
  EXPECT_LT(std::abs(r.pressure_error()), 0.05);
  EXPECT_LT(r.max_speed, 0.25 * r.capillary_speed);
}

TEST(FlipSurfaceTension, LaplacePressureInADiskAtRest) {
  check_drop_at_rest(slurry_test::drop_at_rest<2>(/*cells across the radius*/ 16, /*seconds*/ 2.0),
                     "2D disk, R = 16 dx (Laplace sigma / R)");
}

TEST(FlipSurfaceTension, LaplacePressureInABallAtRest) {
  check_drop_at_rest(slurry_test::drop_at_rest<3>(8, 1.0), "3D ball, R = 8 dx (Laplace 2 sigma / R)");
}

// Spurious currents (Francois et al. 2006, "A balanced-force algorithm for continuous and sharp
// interfacial surface tension models within a volume tracking framework", J. Comput. Phys.
// 213): a viscous drop at rest, Ohnesorge number mu / sqrt(rho sigma R) = 1, so that the
// capillary waves its seeding's staircase starts are damped within its viscous time
// rho R^2 / mu = 4 s; what flow remains is the method's own. Measured as the capillary number
// Ca = mu |u|max / sigma over the last quarter of 4 s.
TEST(FlipSurfaceTension, SpuriousCurrentsAroundAViscousDiskAtRest) {
  const double mu = std::sqrt(1000 * 1.0 * slurry_test::kDropRadius);
  const DropRun r = slurry_test::drop_at_rest<2>(16, 4.0, 1.0, mu);
  const double ca = mu * r.late_speed / 1.0;
  std::printf("[ figure ] viscous 2D disk (Oh = 1), R = 16 dx: largest speed over the last second %.3g m/s, capillary "
              "number %.3g (largest over the run %.3g m/s); pressure error %.3f%%\n",
              r.late_speed, ca, r.max_speed, 100 * r.pressure_error());
  EXPECT_LT(ca, 1e-2);  // 3.9e-3 measured
  EXPECT_LT(std::abs(r.pressure_error()), 0.05);
}

/// Prints and checks a mode-2 oscillation: at least two half periods, the period within 5% of
/// Rayleigh's.
void check_rayleigh(const slurry_test::Oscillation& r, const char* what) {
  std::printf("[ figure ] %s, mode 2, amplitude 5%%: period %.4f s, Rayleigh %.4f s, error %.3f%% (%d half periods)\n", what,
              r.period, r.rayleigh, 100 * (r.period / r.rayleigh - 1), r.half_periods);
  ASSERT_GE(r.half_periods, 2);
  EXPECT_LT(std::abs(r.period / r.rayleigh - 1), 0.05);
}

TEST(FlipSurfaceTension, OscillatingDiskHasRayleighsPeriod) {
  check_rayleigh(slurry_test::oscillating_drop<2>(24, 0.05, 2), "2D disk, R = 24 dx");
}

TEST(FlipSurfaceTension, OscillatingBallHasRayleighsPeriod) {
  check_rayleigh(slurry_test::oscillating_drop<3>(8, 0.05, 2), "3D ball, R = 8 dx");
}

// Without surface tension the disk neither holds a pressure nor oscillates: the checks above
// see the surface tension, not something else.
TEST(FlipSurfaceTension, WithoutSurfaceTensionTheDiskHasNoLaplacePressure) {
  const DropRun r = slurry_test::drop_at_rest<2>(16, 0.2, /*sigma*/ 0);
  std::printf("[ figure ] 2D disk without surface tension: mean pressure inside %.3g Pa\n", r.mean_pressure);
  EXPECT_LT(std::abs(r.mean_pressure), 1e-6);
}

// The curvature and the surface pressure are per-cell loops: frames are bitwise the same for
// one and two threads (also run under ThreadSanitizer, docs/testing.md).
TEST(FlipSurfaceTension, OscillatingDiskIsThreadIndependent) {
  const auto run = [](int threads) {
    slurry::parallel::ThreadLimit limit(threads);
    slurry::Scene s = slurry_test::drop_scene<2>(8, 1.0);
    slurry::flip::FlipSolver<double, 2> sim(s);
    for (auto& x : sim.particles().x) x[0] = 0.5 + 1.1 * (x[0] - 0.5);
    for (int k = 0; k < 20; ++k) sim.step(sim.stable_dt());
    return sim.particles().x;
  };
  const auto one = run(1), two = run(2);
  ASSERT_EQ(one.size(), two.size());
  std::size_t differ = 0;
  for (std::size_t p = 0; p < one.size(); ++p) differ += one[p] != two[p];
  std::printf("[ figure ] 2D drop, 20 steps: %zu of %zu particle positions differ between 1 and 2 threads\n", differ,
              one.size());
  EXPECT_EQ(differ, 0u);
}

TEST(FlipSurfaceTension, TheStepRespectsTheCapillaryLimit) {
  Scene s = slurry_test::drop_scene<2>(16, 1.0);
  slurry::flip::FlipSolver<double, 2> sim(s);
  const double dx = s.domain.dx, limit = 0.5 * std::sqrt(0.5 * 1000 * dx * dx * dx / (2 * M_PI * 1.0));
  std::printf("[ figure ] half the capillary limit %.5f s at dx %.5f m, sigma 1 N/m, rho 1000 kg/m^3\n", limit, dx);
  EXPECT_NEAR(sim.stable_dt(), limit, 1e-12 * limit);
  s.materials[0].surface_tension = 0;
  slurry::flip::FlipSolver<double, 2> still(s);
  EXPECT_DOUBLE_EQ(still.stable_dt(), s.solver.max_dt);
}

TEST(FlipSurfaceTension, BadSurfaceTensionIsRefusedNamingTheKey) {
  const auto scene = slurry_test::material_scene_text;
  const auto message = slurry_test::scene_error;
  const std::string flip = R"({"type": "flip", "dimension": 2})";
  const auto has = [](const std::string& text, const std::string& part) {
    EXPECT_NE(text.find(part), std::string::npos) << text;
  };
  has(message(scene(flip, R"({"name": "a", "model": "fluid", "surface_tension": -0.07})")),
      "bad.json: materials[0].surface_tension: expected a finite number >= 0 (N/m), got -0.07");
  has(message(scene(flip, R"({"name": "a", "model": "fluid", "surface_tension": "water"})")), "materials[0].surface_tension");
  has(message(scene(flip, R"({"name": "a", "model": "fluid", "surface_tension": 0.07},
                             {"name": "b", "model": "fluid", "surface_tension": 0.02})")),
      "materials[1].surface_tension: the FLIP solver takes one surface tension for all liquids: expected 0.07");
  has(message(scene(R"({"type": "mpm", "dimension": 2})", R"({"name": "a", "model": "fluid", "surface_tension": 0.07})")),
      "materials[0].surface_tension: unknown key");
  Scene s = slurry_test::drop_scene<2>(16, std::numeric_limits<double>::quiet_NaN());
  try {
    s.validate();
    ADD_FAILURE() << "accepted a NaN surface tension";
  } catch (const slurry::SceneError& e) {
    has(e.what(), "materials[0].surface_tension: expected a finite number >= 0 (N/m), got nan");
  }
  EXPECT_EQ(message(scene(flip, R"({"name": "a", "model": "fluid", "surface_tension": 0.0728})")), "accepted");
  EXPECT_DOUBLE_EQ(
      slurry::parse_scene(scene(flip, R"({"name": "a", "model": "fluid", "surface_tension": 0.0728})"), "ok.json")
          .materials[0]
          .surface_tension,
      0.0728);
}

}  // namespace
