// The extremes suite, float precision far from the origin.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "extremes.h"

namespace {

using extremes::Outcome;
using slurry::Scene;

/// The 2D landing block of the MPM cases (dx = 1/32 m), its domain shifted by `offset` in x and y.
Scene shifted_block(double offset, slurry::Precision precision) {
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.03125},
    "solver": {"dimension": 2, "precision": "float"},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.375, 0.1], "max": [0.625, 0.35], "material": "jelly", "particles_per_cell": 4}],
    "output": {"fps": 40, "frames": 6}
  })", "far_from_origin");
  s.solver.precision = precision;
  const Eigen::Vector3d shift(offset, offset, 0);
  s.domain.min += shift;
  s.domain.max += shift;
  s.bodies[0].min += shift;
  s.bodies[0].max += shift;
  return s;
}

struct Trajectory {
  Outcome outcome;
  double com_y = 0;  // centre of mass height above the domain floor at the end (m)
};

Trajectory run_shifted(double offset, slurry::Precision precision) {
  Trajectory t;
  const Scene s = shifted_block(offset, precision);
  t.outcome = extremes::run(s, 6, [&](const slurry::Table& v) {
    double sum = 0;
    for (double y : v.column_as_double("y")) sum += y - offset;
    t.com_y = sum / double(v.count);
  });
  return t;
}

// What happens: a float scene 1e4 m from the origin (dx = 1/32 m, 3.2e5 cells out) resolves
// positions to 1e-3 m; before the guard, the landing block ran but ended 0.13 cells lower than
// at the origin, with 5% energy growth and a smallest J of 0.715 instead of 0.776 (figures at
// 3e3 m: 0.065 cells; 1e3 m: 0.0037 cells; 1e2 m: 0.0003 cells). The guard (Scene::validate)
// refuses float beyond 32768 cells from the origin and names both ways out.
TEST(ExtremesPrecision, FloatFarFromTheOriginIsRefusedWithTheWayOut) {
  const Trajectory far = run_shifted(1e4, slurry::Precision::Float);
  extremes::expect_stops("float, domain at 1e4 m (dx 1/32 m)", far.outcome,
                         "solver.precision: \"float\" resolves positions 1e+04 m from the origin only to 0.00119 m");
  EXPECT_NE(far.outcome.message.find("use \"precision\": \"double\", or move the scene's origin into the domain"),
            std::string::npos)
      << far.outcome.message;
  // FLIP scenes are guarded alike (parse_scene validates).
  try {
    slurry::parse_scene(R"({
      "domain": {"min": [10000, 10000], "max": [10001, 10001], "dx": 0.03125},
      "solver": {"type": "flip", "dimension": 2, "transfer": "apic", "kernel": "quadratic"},
      "materials": [{"name": "water", "model": "fluid"}],
      "bodies": [{"shape": "box", "min": [10000.25, 10000.25], "max": [10000.75, 10000.5], "material": "water"}]
    })", "far_flip");
    ADD_FAILURE() << "a float FLIP scene at 1e4 m was accepted";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("far_flip: solver.precision: \"float\" resolves"), std::string::npos) << e.what();
  }
}

// Double precision at 1e4 m follows the run at the origin to 1e-9 cells; float at 1e3 m
// (32000 cells out, just inside the guard) to 0.01 cells, with the same energy.
TEST(ExtremesPrecision, DoubleFarAwayAndFloatWithinTheGuardFollowTheOrigin) {
  const Trajectory ref = run_shifted(0, slurry::Precision::Double);
  const Trajectory dbl = run_shifted(1e4, slurry::Precision::Double);
  extremes::expect_runs("double, domain at 1e4 m", dbl.outcome, 6, 1.01);
  EXPECT_NEAR(dbl.com_y, ref.com_y, 1e-9 * 0.03125);
  const Trajectory flt = run_shifted(1e3, slurry::Precision::Float);
  extremes::expect_runs("float, domain at 1e3 m", flt.outcome, 6, 1.01);
  std::printf("[ extreme ] centre of mass vs double at the origin: double at 1e4 m %.3g cells, float at 1e3 m %.3g cells\n",
              (dbl.com_y - ref.com_y) / 0.03125, (flt.com_y - ref.com_y) / 0.03125);
  EXPECT_NEAR(flt.com_y, ref.com_y, 0.01 * 0.03125);
  EXPECT_NEAR(flt.outcome.energy_ratio, ref.outcome.energy_ratio, 1e-3);
}

}  // namespace
