// The extremes suite, MPM solids: stiffness, Poisson's ratio, density, impact
// speed, compression, one-particle bodies, thin colliders, the Courant numbers at their bounds
// and every transfer x kernel pair. The outcome of each case (runs or stops) is asserted; the
// figures go to tests/extremes/README.md.
#include <gtest/gtest.h>

#include <cmath>
#include <array>
#include <string>
#include <utility>
#include <vector>

#include "extremes.h"

namespace {

using extremes::expect_runs;
using extremes::expect_stops;
using extremes::Outcome;
using slurry::Scene;

/// A 2D elastic block (0.25 m square, 4 particles per cell, dx = 1/32 m) released at rest 4 cm
/// above the floor of a 1 m box: it lands after about 0.09 s. Float precision, MLS, quadratic.
Scene block_2d(double E, double nu, double density) {
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.03125},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "model": "fixed_corotated"}],
    "bodies": [{"shape": "box", "min": [0.375, 0.1], "max": [0.625, 0.35], "material": "jelly", "particles_per_cell": 4}],
    "output": {"fps": 40, "frames": 6}
  })", "block_2d");
  s.materials[0].E = E;
  s.materials[0].nu = nu;
  s.materials[0].density = density;
  return s;
}

std::string sci(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", v);
  return b;
}

// Young's modulus over eight decades with the automatic (elastic) step: every block lands and
// settles without energy growth. The substep limit caps the work (a runaway step count is an
// error, never a hang).
TEST(Extremes, YoungsModulusFrom1e2To1e10Explicit) {
  for (double E : {1e2, 1e4, 1e6, 1e8, 1e10}) {
    Scene s = block_2d(E, 0.3, 1000);
    s.limits.substeps_per_frame = 20000;
    const Outcome o = extremes::run(s, 6);
    expect_runs("explicit E = " + sci(E), o, 6, 1.02);
  }
}

// The implicit integrator at 10 and 100 times the explicit elastic limit (double: its IC(0)
// preconditioner), for a stiff and a very stiff block.
TEST(Extremes, YoungsModulusImplicitAt10And100TimesTheExplicitLimit) {
  for (double E : {1e6, 1e10}) {
    for (double factor : {10.0, 100.0}) {
      Scene s = block_2d(E, 0.3, 1000);
      s.solver.precision = slurry::Precision::Double;
      const double explicit_dt = s.elastic_dt();
      s.solver.integrator = slurry::Integrator::Implicit;
      s.solver.max_dt = factor * explicit_dt;
      s.output.frames = 3;
      const Outcome o = extremes::run(s, 3);
      expect_runs("implicit E = " + sci(E) + " at " + sci(factor) + "x the explicit limit (dt " + sci(s.solver.max_dt) + " s)",
                  o, 3, 1.02);
    }
  }
}

// Nearly incompressible (nu = 0.499: lambda = 333 mu) explicit and implicit.
TEST(Extremes, PoissonRatio0499) {
  Scene s = block_2d(1e5, 0.499, 1000);
  expect_runs("nu = 0.499 explicit", extremes::run(s, 6), 6, 1.02);
  s.solver.precision = slurry::Precision::Double;
  s.solver.max_dt = 30 * s.elastic_dt();
  s.solver.integrator = slurry::Integrator::Implicit;
  expect_runs("nu = 0.499 implicit at 30x", extremes::run(s, 6), 6, 1.02);
}

// Densities from 1 to 2e4 kg/m^3, and the two softest-heaviest / stiffest-lightest corners.
TEST(Extremes, DensityFrom1To2e4) {
  for (double rho : {1.0, 2e4}) {
    const Outcome o = extremes::run(block_2d(1e5, 0.3, rho), 6);
    expect_runs("density " + sci(rho), o, 6, 1.02);
  }
  // E = 1e2 Pa under 2e4 kg/m^3: the static strain rho g h / E is about 500, the block
  // collapses into a puddle; it must stay finite and inside.
  const Outcome soft = extremes::run(block_2d(1e2, 0.3, 2e4), 6);
  expect_runs("E = 1e2, density 2e4", soft, 6, 1.02);
  // E = 1e10 Pa at 1 kg/m^3: wave speed 1.2e5 m/s, substep 1.3e-7 s; two short frames.
  Scene stiff = block_2d(1e10, 0.3, 1);
  stiff.output.fps = 2000;
  const Outcome o = extremes::run(stiff, 2);
  expect_runs("E = 1e10, density 1", o, 2, 1.02);
}


/// A 2D box [0, 1] x [0, 0.5] (dx = 1/32 m) with elastic blocks of the given x ranges and
/// horizontal velocities, 0.2 m tall, resting 3 cm above the floor.
Scene impact_2d(std::vector<std::array<double, 3>> blocks, slurry::ElasticModel model = slurry::ElasticModel::FixedCorotated) {
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 0.5], "dx": 0.03125},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.1], "max": [0.2, 0.2], "material": "jelly"}],
    "output": {"fps": 500, "frames": 10}
  })", "impact_2d");
  s.materials[0].model = model;
  const slurry::BodyParams b = s.bodies[0];
  s.bodies.clear();
  for (const auto& [x0, x1, vx] : blocks) {
    slurry::BodyParams c = b;
    c.min = {x0, 0.1, 0};
    c.max = {x1, 0.3, 0};
    c.velocity = {vx, 0, 0};
    c.particles_per_cell = 4;
    s.bodies.push_back(c);
  }
  return s;
}

// 100 m/s into the right wall (2 ms to reach it, 20 ms run), with every elastic model. The jelly
// (E = 1e5 Pa, wave speed 11.6 m/s) hits at Mach 9 and is crushed against the wall (J down to
// 1e-5). At the default solver.max_dt (1 ms) the step after the block has come to rest is the
// full max_dt, and the rebound of the crushed layer moves particles more than a cell in it: the
// run stops with the CFL diagnosis, which names solver.max_dt. With max_dt = 1e-4 s it runs.
Outcome impact(std::vector<std::array<double, 3>> blocks, slurry::ElasticModel model, double max_dt) {
  Scene s = impact_2d(std::move(blocks), model);
  s.solver.max_dt = max_dt;
  return extremes::run(s, 10);
}

TEST(Extremes, HundredMetresPerSecondIntoAWall) {
  using M = slurry::ElasticModel;
  for (M model : {M::FixedCorotated, M::CorotatedLinear, M::NeoHookean, M::StVK, M::HenckyStVK}) {
    const std::string name = std::string("100 m/s into a wall, ") + std::string(slurry::to_string(model));
    const Outcome fine = impact({{{0.6, 0.8, 100.0}}}, model, 1e-4);
    expect_runs(name + ", max_dt 1e-4", fine, 10, 1.01);
    const Outcome dflt = impact({{{0.6, 0.8, 100.0}}}, model, 1e-3);
    if (dflt.stopped)
      expect_stops(name + ", max_dt 1e-3", dflt, "CFL violation");
    else
      expect_runs(name + ", max_dt 1e-3", dflt, 10, 1.01);
  }
}

// Two blocks at 100 m/s each, head on (200 m/s closing speed), 2D and 3D.
TEST(Extremes, HundredMetresPerSecondIntoEachOther) {
  const Outcome o = impact({{{0.2, 0.4, 100.0}}, {{0.6, 0.8, -100.0}}}, slurry::ElasticModel::FixedCorotated, 1e-4);
  expect_runs("two blocks at 100 m/s head on, max_dt 1e-4", o, 10, 1.01);
  const Outcome d = impact({{{0.2, 0.4, 100.0}}, {{0.6, 0.8, -100.0}}}, slurry::ElasticModel::FixedCorotated, 1e-3);
  expect_stops("two blocks at 100 m/s head on, max_dt 1e-3", d, "CFL violation");
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0, 0], "max": [1, 0.375, 0.375], "dx": 0.0625},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.125, 0.125], "max": [0.35, 0.25, 0.25], "material": "jelly", "velocity": [100, 0, 0]},
               {"shape": "box", "min": [0.65, 0.125, 0.125], "max": [0.9, 0.25, 0.25], "material": "jelly", "velocity": [-100, 0, 0]}],
    "output": {"fps": 500, "frames": 10}
  })", "impact_3d");
  expect_runs("3D: two cubes at 100 m/s head on", extremes::run(s, 10), 10, 1.01);
}

// Compression to J = 0.05: a block filling a 0.25 m wide column between slip walls, 1 m tall,
// squeezed by a piston (a half-space collider) moving down at 2 m/s until the gap is 5% of the
// block's height. Lateral expansion is blocked, so the mean J follows the gap. The piston does
// work on the block; the energy bound allows 1.5x the initial energy plus the quasi-static work
// of uniaxial compression V0 (mu + lambda / 2) (1 - J)^2 (fixed corotated, F = diag(1, J)).
Outcome compress(slurry::ElasticModel model, double* mean_J) {
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [0.25, 1.25], "dx": 0.015625},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0, 0], "max": [0.25, 1.0], "material": "jelly", "particles_per_cell": 4}],
    "boundaries": {"walls": "slip"},
    "colliders": [{"shape": "half_space", "point": [0, 1.0], "normal": [0, -1], "velocity": [0, -2], "condition": "slip"}],
    "output": {"fps": 21.05263157894737, "frames": 10}
  })", "compression");
  s.materials[0].model = model;
  double last_mean = 0;
  Outcome o = extremes::run(s, 10, [&](const slurry::Table& v) {
    const auto J = v.column_as_double("J");
    double sum = 0;
    for (double j : J) sum += j;
    last_mean = sum / double(J.size());
  });
  *mean_J = last_mean;
  return o;
}

TEST(Extremes, CompressionToJ005) {
  const double E = 1e5, nu = 0.3, rho = 1000, V0 = 0.25, h0 = 1.0, J = 0.05;
  const double mu = E / (2 * (1 + nu)), lambda = E * nu / ((1 + nu) * (1 - 2 * nu));
  const double E0 = rho * V0 * 9.81 * h0 / 2, work = V0 * (mu + lambda / 2) * (1 - J) * (1 - J);
  double mean_J = 0;
  const Outcome o = compress(slurry::ElasticModel::FixedCorotated, &mean_J);
  expect_runs("compression to J = 0.05 (fixed corotated)", o, 10, 1.5 * (E0 + work) / E0);
  std::printf("[ extreme ] compression: mean J %.4f at the end, min J %.4f\n", mean_J, o.min_J);
  EXPECT_LT(mean_J, 0.08) << "the piston compressed the block to about J = 0.05";
  EXPECT_GT(o.min_J, 0.0) << "no particle inverted";
}

// A body one particle thick (a row in 2D, a sheet in 3D) and a single particle, dropped 0.4 m.
TEST(Extremes, BodyOneParticleThick) {
  Scene s = block_2d(1e5, 0.3, 1000);
  s.bodies[0].min = {0.3, 0.5, 0};
  s.bodies[0].max = {0.7, 0.5 + 0.03125 / 2, 0};  // one particle spacing at 4 per cell
  s.output.fps = 20;
  int rows = 0;
  const Outcome o = extremes::run(s, 10, [&](const slurry::Table& v) {
    if (rows == 0) rows = int(v.count);
  });
  EXPECT_EQ(rows, 26) << "one row of 0.4 m / (dx / 2)";
  expect_runs("a row one particle thick (2D)", o, 10, 1.02);

  s.bodies[0].max = {0.3 + 0.03125 / 2, 0.5 + 0.03125 / 2, 0};  // one particle
  const Outcome one = extremes::run(s, 10);
  EXPECT_EQ(one.particles, 1u);
  expect_runs("a single particle (2D)", one, 10, 1.02);

  Scene t = slurry::parse_scene(R"({
    "domain": {"min": [0, 0, 0], "max": [0.5, 0.5, 0.5], "dx": 0.03125},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.3, 0.1], "max": [0.4, 0.315625, 0.4], "material": "jelly"}],
    "output": {"fps": 20, "frames": 6}
  })", "sheet_3d");
  expect_runs("a sheet one particle thick (3D)", extremes::run(t, 6), 6, 1.02);
}

// A thin wall: a box collider a quarter of a cell thick across the whole domain at x = 0.5,
// hit at 20 and 100 m/s. No particle may end up on its far side, nor inside it. Before the
// particle-level check for thin colliders (mpm_solver_impl.h, detail::keep_out_of_colliders)
// the block passed the wall at 20 m/s: particles took the velocity of the nodes beyond it, and
// 0.29 m of the block came out on the far side. A wall 8 cells thick is held by the grid alone:
// particles sink into it (up to 1.3 cells, sticky), never through.
TEST(Extremes, ThinWallColliderHitAtSpeed) {
  const double dx = 0.03125;
  for (double thickness : {dx / 4, 8 * dx}) {
    for (double speed : {20.0, 100.0}) {
      for (auto condition : {slurry::Condition::Separate, slurry::Condition::Sticky}) {
        Scene s = impact_2d({{{0.2, 0.4, speed}}});
        s.solver.max_dt = speed > 50 ? 1e-4 : 1e-3;  // as for the wall at 100 m/s
        slurry::ColliderParams wall;
        wall.shape = slurry::ColliderShape::Box;
        wall.min = {0.5, -1, 0};
        wall.max = {0.5 + thickness, 2, 0};
        wall.condition = condition;
        s.colliders = {wall};
        double far = -1;
        const Outcome o = extremes::run(s, 10, [&](const slurry::Table& v) {
          for (double x : v.column_as_double("x")) far = std::max(far, x - 0.5);
        });
        const std::string name = "wall " + sci(thickness / dx) + " dx thick hit at " + sci(speed) + " m/s, " +
                                 (condition == slurry::Condition::Sticky ? "sticky" : "separate");
        expect_runs(name, o, 10, 1.01);
        std::printf("[ extreme ] %s: largest x - 0.5 = %.4g m\n", name.c_str(), far);
        if (thickness < dx)
          EXPECT_LE(far, 0.0) << name << ": a particle entered or passed the wall";
        else
          EXPECT_LT(far, 2 * dx) << name << ": a particle sank more than two cells into the wall";
      }
    }
  }
}

// The Courant numbers at their bounds. Upper: cfl = 1 and elastic_cfl = 1 (the largest values
// validate() accepts) on a stiff block hitting the wall at 10 m/s, for the three kernels.
// Lower: a vanishing cfl or elastic_cfl is refused with a message naming the key (the
// time-step floor), and a small one (0.01) runs.
TEST(Extremes, CourantNumbersAtTheirBounds) {
  using K = slurry::KernelKind;
  using T = slurry::TransferKind;
  for (auto [transfer, kernel] : {std::pair{T::APIC, K::Linear}, std::pair{T::MLS, K::Quadratic}, std::pair{T::MLS, K::Cubic}}) {
    Scene s = impact_2d({{{0.6, 0.8, 10.0}}});
    s.materials[0].E = 1e7;
    s.solver.transfer = transfer;
    s.solver.kernel = kernel;
    s.solver.cfl = 1;
    s.solver.elastic_cfl = 1;
    s.output.fps = 100;
    const Outcome o = extremes::run(s, 5);
    const std::string name = std::string("cfl = elastic_cfl = 1, ") + std::string(slurry::to_string(transfer)) + " " +
                             std::string(slurry::to_string(kernel));
    // The linear kernel's elastic limit (a quarter of elastic_cfl dx / c, mpm_solver_impl.h) is
    // not enough at elastic_cfl = 1: the block's energy grows (x1.5) until a particle is thrown
    // out of the domain, and the run stops with the diagnosis. The B-splines run.
    if (kernel == K::Linear)
      expect_stops(name, o, "left the domain");
    else
      expect_runs(name, o, 5, 1.01);
  }
  {
    Scene s = impact_2d({{{0.6, 0.8, 10.0}}});
    s.solver.cfl = 0.01;
    s.solver.elastic_cfl = 0.01;
    s.output.fps = 1000;
    expect_runs("cfl = elastic_cfl = 0.01", extremes::run(s, 5), 5, 1.01);
  }
  {
    Scene s = impact_2d({{{0.6, 0.8, 10.0}}});
    s.solver.cfl = 1e-12;
    expect_stops("cfl = 1e-12", extremes::run(s, 5), "solver.cfl: the substep fell to");
  }
  {
    Scene s = impact_2d({{{0.6, 0.8, 10.0}}});
    s.solver.elastic_cfl = 1e-12;
    expect_stops("elastic_cfl = 1e-12", extremes::run(s, 5), "solver.elastic_cfl: the elastic limit");
  }
  {
    Scene s = impact_2d({{{0.6, 0.8, 10.0}}});
    s.solver.cfl = 1.0000001;
    expect_stops("cfl above 1", extremes::run(s, 5), "solver.cfl: expected a number in (0, 1]");
  }
}

// Every transfer x kernel pair in 2D and 3D: a block thrown at (3, -5) m/s onto the floor.
// MLS with the linear kernel is refused by validation (its D_p^-1 is not constant).
void transfer_kernel_pairs(int dim) {
  using K = slurry::KernelKind;
  using T = slurry::TransferKind;
  for (T transfer : {T::PIC, T::FLIP, T::APIC, T::MLS}) {
    for (K kernel : {K::Linear, K::Quadratic, K::Cubic}) {
      Scene s = dim == 2 ? slurry::parse_scene(R"({
        "domain": {"min": [0, 0], "max": [1, 0.5], "dx": 0.03125},
        "solver": {"dimension": 2},
        "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
        "bodies": [{"shape": "box", "min": [0.3, 0.2], "max": [0.5, 0.4], "material": "jelly", "velocity": [3, -5], "particles_per_cell": 4}],
        "output": {"fps": 50, "frames": 5}
      })", "pairs_2d")
                         : slurry::parse_scene(R"({
        "domain": {"min": [0, 0, 0], "max": [0.5, 0.5, 0.5], "dx": 0.0625},
        "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
        "bodies": [{"shape": "box", "min": [0.125, 0.25, 0.125], "max": [0.3125, 0.4375, 0.3125], "material": "jelly", "velocity": [3, -5, 0]}],
        "output": {"fps": 50, "frames": 5}
      })", "pairs_3d");
      s.solver.transfer = transfer;
      s.solver.kernel = kernel;
      const std::string name = std::to_string(dim) + "D " + std::string(slurry::to_string(transfer)) + " " +
                               std::string(slurry::to_string(kernel));
      const Outcome o = extremes::run(s, 5);
      if (transfer == T::MLS && kernel == K::Linear) {
        expect_stops(name, o, "solver.kernel: transfer \"mls\" needs kernel \"quadratic\" or \"cubic\"");
      } else if (transfer == T::FLIP && kernel == K::Linear && dim == 2) {
        // Open: the FLIP blend with the linear kernel throws a particle out of the domain after
        // the impact (the energy grows x2.6 first); the diagnosis stops the run.
        expect_stops(name, o, "left the domain");
      } else if (transfer == T::FLIP) {
        // FLIP (flip_ratio 0.95) keeps the velocity noise of the impact on the particles (only
        // the 5% PIC share damps it): the energy counted on particle velocities grows up to
        // x2.5 within 0.1 s. Bounded here by 3; use APIC or MLS for solids.
        expect_runs(name, o, 5, 3.0);
      } else if (kernel == K::Linear && dim == 2 && o.stopped) {
        // Open: APIC with the linear kernel inverts a particle in the 2D impact (J < 0) and gains
        // energy (x1.14 with the bins in storage order): the cell-crossing error of the linear kernel, whose
        // gradient jumps as a particle crosses a cell face (Bardenhagen and Kober 2004, "The
        // generalized interpolation material point method"). Whether the run then survives the
        // 5 frames, and which diagnosis stops it, depends on the last bits of the sums: with
        // bins ordered by id it stopped at step 201 with the CFL diagnosis (a particle at
        // 135 m/s); with the closed-form 2D polar rotation at step 233 with a particle out of
        // the domain. Either outcome is allowed, if the stop is the instability
        // diagnosis; a silent blow-up, an energy gain above the bound below, or another stop is
        // not.
        expect_stops(name, o, "simulation unstable at step");
      } else if (kernel == K::Linear) {
        // The linear kernel: APIC's energy grows x1.14 in 2D (an inverted particle, J < 0).
        expect_runs(name, o, 5, 1.2);
      } else {
        expect_runs(name, o, 5, 1.01);
      }
    }
  }
}

TEST(Extremes, EveryTransferKernelPair2D) { transfer_kernel_pairs(2); }
TEST(Extremes, EveryTransferKernelPair3D) { transfer_kernel_pairs(3); }

}  // namespace

// A CFL-limited substep that collapsed below the floor because velocities blew up (a FLIP
// liquid squeezed by a mesh paddle against the floor reached 1e9 m/s) is an instability
// (SimulationError: exit 1, retried with solver.on_instability "retry"), with a diagnosis that
// says so, not a setting to raise. A tiny cfl at ordinary speeds is still the setting's error.
TEST(Extremes, CollapsedStepFromABlowUpIsAnInstability) {
  Scene s = block_2d(1e5, 0.3, 1000);  // at rest, dx = 1/32 m, cfl 0.5
  try {
    slurry::substep_limit_error(s, 1e-11, 1.0 / 40, 3, 0.45);
    FAIL() << "no error";
  } catch (const slurry::SimulationError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("simulation unstable at t = 0.45 s: particles reached 1.56e+09 m/s"), std::string::npos) << m;
    EXPECT_NE(m.find("the state blew up"), std::string::npos) << m;
  }
  s.solver.cfl = 1e-12;  // the same substep at 0.0031 m/s: the setting is what makes it small
  try {
    slurry::substep_limit_error(s, 1e-11, 1.0 / 40, 3, 0.45);
    FAIL() << "no error";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("solver.cfl: the substep fell to"), std::string::npos) << e.what();
  }
}
