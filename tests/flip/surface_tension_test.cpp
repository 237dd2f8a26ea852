// Surface tension of the FLIP liquid (surface_tension.h, ghost-fluid pressure jump): the pressure
// inside a drop at rest against Laplace's sigma / R (2D) and 2 sigma / R (3D), the spurious
// currents around it, the period of a drop's mode-2 oscillation against Rayleigh's, the
// capillary time step limit, a glycerol puddle's height against the capillary length, and the
// scene key's bad values. The sizes here are CI's; the
// same checks at finer grids carry the label `validation` (surface_tension_validation_test.cpp).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/transfer/parallel.h"
#include "liquid_scene.h"
#include "oscillation_checks.h"
#include "slurry/io/scene_file.h"
#include "surface_tension_drop.h"

namespace {

using slurry::Scene;
using slurry_test::check_rayleigh;
using slurry_test::check_sustained;
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

// The same disk over 48 s, twelve capillary times sqrt(rho R^3 / sigma): the capillary waves
// of its seeding keep it moving (inviscid), and the question is whether that motion stays
// bounded. It did not while the volume correction's share was removed every substep (at the
// capillary step, 1/23 of an advective one for water at dx = 0.5 mm): its pushes into the sparse
// cells that the waves leave fed the motion until the drop burst at 45 s (largest speed over
// the run 1.96 of the capillary speed). With the share removed per advective step the largest speed stays at
// the seeding's 0.07; by 60 s it has crept up to 0.18 (a slower growth, not yet understood).
TEST(FlipSurfaceTension, DiskAtRestStaysAtRestForTwelveCapillaryTimes) {
  const DropRun r = slurry_test::drop_at_rest<2>(16, 48.0);
  std::printf("[ figure ] 2D disk, R = 16 dx, 48 s: largest speed %.3g of sqrt(sigma / (rho R)), over the last quarter %.3g\n",
              r.max_speed / r.capillary_speed, r.late_speed / r.capillary_speed);
  EXPECT_LT(r.max_speed, 0.25 * r.capillary_speed);
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
  EXPECT_LT(ca, 1e-2);  // 4.05e-3 measured
  EXPECT_LT(std::abs(r.pressure_error()), 0.05);
}

/// A half drop (the upper half of the disk or ball) resting on a wall at `floor`: the domain's
/// floor (floor = 0) or the top of a box collider under it. The surface meets the wall at
/// 90 degrees, the contact angle the mirrored stencils impose, so the half drop is at rest: its
/// largest speed over `seconds` and its largest particle's distance from the centre, relative to
/// R, are returned.
template <int Dim>
std::pair<double, double> half_drop_on_a_wall(int cells_per_radius, double seconds, double floor) {
  slurry::flip::FlipSolver<double, Dim> sim(slurry_test::drop_on_a_wall_scene<Dim>(cells_per_radius, 1.0, floor));
  slurry_test::half_drop_on_the_wall(sim, floor);
  const auto& P = sim.particles();
  Eigen::Matrix<double, Dim, 1> centre = Eigen::Matrix<double, Dim, 1>::Constant(0.5);
  centre[1] = floor;
  double speed = 0, reach = 0;
  while (sim.time() < seconds - 1e-12) {
    sim.step(std::min(sim.stable_dt(), 0.05));
    speed = std::max(speed, double(sim.max_speed()));
    for (const auto& x : P.x) reach = std::max(reach, (x - centre).norm());
  }
  return {speed / std::sqrt(1.0 / (slurry_test::kDropDensity * slurry_test::kDropRadius)), reach / slurry_test::kDropRadius};
}

// A half drop on a wall stays a half drop. With the wall's cells repeated in the curvature's
// stencils instead (the normal's wall component even instead of odd), the curvature at the
// contact line came out a quarter low, and the liquid crept out along the wall.
TEST(FlipSurfaceTension, HalfDropOnTheFloorStaysAtRest) {
  const auto [speed, reach] = half_drop_on_a_wall<2>(16, 8.0, 0.0);
  std::printf("[ figure ] 2D half disk on the domain's floor, R = 16 dx, 8 s: largest speed %.3g of sqrt(sigma / (rho "
              "R)), farthest particle %.3f R\n",
              speed, reach);
  EXPECT_LT(speed, 0.25);
  EXPECT_LT(reach, 1.1);
}

TEST(FlipSurfaceTension, HalfDropOnACollidersTopStaysAtRest) {
  const auto [speed, reach] = half_drop_on_a_wall<2>(16, 8.0, 0.125);
  std::printf("[ figure ] 2D half disk on a box collider, R = 16 dx, 8 s: largest speed %.3g of sqrt(sigma / (rho R)), "
              "farthest particle %.3f R\n",
              speed, reach);
  EXPECT_LT(speed, 0.25);
  EXPECT_LT(reach, 1.1);
}

TEST(FlipSurfaceTension, HalfBallOnTheFloorStaysAtRest) {
  const auto [speed, reach] = half_drop_on_a_wall<3>(8, 6.0, 0.0);
  std::printf("[ figure ] 3D half ball on the domain's floor, R = 8 dx, 6 s: largest speed %.3g of sqrt(sigma / (rho "
              "R)), farthest particle %.3f R\n",
              speed, reach);
  EXPECT_LT(speed, 0.25);
  EXPECT_LT(reach, 1.1);
}

TEST(FlipSurfaceTension, OscillatingDiskHasRayleighsPeriod) {
  const auto r = slurry_test::oscillating_drop<2>(24, 0.05, 4);
  check_rayleigh(r, "2D disk, R = 24 dx");
  check_sustained(r, "2D disk, R = 24 dx", 0.8);
}

// Four periods of a ball of 8 cells. Without the curvature carried to the smoothed surface
// (surface_tension.h, to_surface) the particles of the outermost cells where the equator meets
// a grid axis left the drop from 7.5 s (1.33 R at 10 s), the fourth half period's amplitude was
// 1.29 of the release's, and the kinetic energy at the fifth zero crossing (29 s) nearly 900
// times that at the first.
TEST(FlipSurfaceTension, OscillatingBallHasRayleighsPeriod) {
  const auto r = slurry_test::oscillating_drop<3>(8, 0.05, 8);
  check_rayleigh(r, "3D ball, R = 8 dx");
  check_sustained(r, "3D ball, R = 8 dx", 0.8);
}

// The surface energy of the run's statistics: sigma times the area (length in 2D) of the drop's
// surface, from the colour function's total variation, against 2 pi R and 4 pi R^2; a quarter
// disk in the domain's corner and a half disk on a collider count only their free part.
// Gravity against surface tension: a block of glycerol on the floor settles into a puddle whose
// height is set by the capillary length (surface_tension_drop.h). At dx = 0.5 mm (the height is
// 6.4 cells) it measures 2.9% high after 1 s. Without surface tension the block spreads over the
// whole floor, 1.6 mm high; the height goes as sqrt(sigma), so the 5% bound holds the jump to
// about 10%.
// Finer: the validation label.
TEST(FlipSurfaceTension, GlycerolPuddleHasTheCapillaryHeight) {
  const auto p = slurry_test::glycerol_puddle(0.0005, 1.0);
  std::printf("[ figure ] 2D glycerol puddle, dx = 0.5 mm, 1 s: height %.4f mm, 2 l_c sin 45 = %.4f mm, error %.2f%%, "
              "width %.2f mm\n", 1e3 * p.height, 1e3 * p.expected, 100 * p.error(), 1e3 * p.width);
  EXPECT_LT(std::abs(p.error()), 0.05);
}

TEST(FlipSurfaceTension, SurfaceEnergyIsSigmaTimesTheArea) {
  const auto energy = [](auto& sim) { return sim.take_stats().surface; };
  {
    slurry::flip::FlipSolver<double, 2> sim(slurry_test::drop_scene<2>(16, 2.0));
    const double exact = 2.0 * 2 * M_PI * slurry_test::kDropRadius, got = energy(sim);
    std::printf("[ figure ] 2D disk, R = 16 dx: surface energy %.5f J/m, sigma 2 pi R %.5f J/m, error %.3f%%\n", got, exact,
                100 * (got / exact - 1));
    EXPECT_NEAR(got / exact, 1, 0.015);
  }
  {
    slurry::flip::FlipSolver<double, 3> sim(slurry_test::drop_scene<3>(8, 2.0));
    const double R = slurry_test::kDropRadius, exact = 2.0 * 4 * M_PI * R * R, got = energy(sim);
    std::printf("[ figure ] 3D ball, R = 8 dx: surface energy %.5f J, sigma 4 pi R^2 %.5f J, error %.3f%%\n", got, exact,
                100 * (got / exact - 1));
    EXPECT_NEAR(got / exact, 1, 0.03);
  }
  {
    slurry::Scene s = slurry_test::drop_scene<2>(16, 2.0);
    s.bodies[0].shape = slurry::Shape::Box;  // the corner's square, cut to the quarter disk below
    s.bodies[0].min = Eigen::Vector3d(0, 0, 0);
    s.bodies[0].max = Eigen::Vector3d(0.5, 0.5, 0);
    slurry::flip::FlipSolver<double, 2> sim(s);
    slurry_test::keep_particles(sim.particles(), [](const auto& x) { return x.norm() < 0.5; });
    const double exact = 2.0 * 2 * M_PI * 0.5 / 4, got = energy(sim);
    std::printf("[ figure ] 2D quarter disk in the corner, R = 32 dx: surface energy %.5f J/m, sigma pi R / 2 %.5f J/m, error "
                "%.3f%%\n",
                got, exact, 100 * (got / exact - 1));
    EXPECT_NEAR(got / exact, 1, 0.03);
  }
  {  // a half disk on a box collider, before the first substep (no cell labelled yet) and after
    slurry::flip::FlipSolver<double, 2> sim(slurry_test::drop_on_a_wall_scene<2>(16, 2.0, 0.125));
    slurry_test::half_drop_on_the_wall(sim, 0.125);
    const double exact = 2.0 * M_PI * slurry_test::kDropRadius, before = energy(sim);
    sim.step(sim.stable_dt());
    const double after = energy(sim);
    std::printf("[ figure ] 2D half disk on a collider, R = 16 dx: surface energy %.5f J/m before the first step, %.5f after, "
                "sigma pi R %.5f J/m\n",
                before, after, exact);
    EXPECT_NEAR(before / exact, 1, 0.03);
    EXPECT_NEAR(after / before, 1, 0.01);
  }
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
