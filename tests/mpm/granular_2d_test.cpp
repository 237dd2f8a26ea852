// Dry granular flow in 2D (plane strain) against experiment, fast enough for every CI run: a
// rectangular sand column of length d_i = 0.15 m and height h_i = 0.15 m (aspect ratio a = 1)
// against the left wall collapses onto a rough floor. Lube, Huppert, Sparks and Freundt 2005,
// "Collapses of two-dimensional granular columns", Phys. Rev. E 72, 041301, found for a below
// about 2.3, independently of the grain material,
//   (d_inf - d_i) / d_i = 1.2 a,
// with a scatter of 10-15% between materials. The sand is the study's (benchmarks/tradeoff:
// Drucker-Prager, friction angle 30 degrees, basal friction 0.5) at the production defaults.
// The 2D Drucker-Prager cone is the plane-strain slice of the 3D one (plasticity.h); with the 3D
// cone's coefficient in the 2D deviator the material was weaker in 2D than in 3D and the runout
// grew away from the experiment under refinement (+33% at dx 1/128, +40% at 1/256). Here it
// must lie within 12% of the experiment at dx 1/128 and 1/256, and move towards it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace {

constexpr double kLength = 0.15, kHeight = 0.15;

std::string column_scene(double dx) {
  const double wall = 2 * dx;  // boundaries.thickness cells: the floor and the left wall
  char buf[2048];
  std::snprintf(buf, sizeof buf, R"({
    "domain": {"min": [0, 0], "max": [0.6, 0.3], "dx": %.17g},
    "solver": {"dimension": 2},
    "materials": [{"name": "sand", "model": "hencky_stvk", "density": 2200, "E": 350000.0, "nu": 0.3,
                   "plasticity": "drucker_prager", "friction_angle": 30}],
    "bodies": [{"shape": "box", "min": [%.17g, %.17g], "max": [%.17g, %.17g], "material": "sand"}],
    "boundaries": {"walls": "separate", "friction": 0.5},
    "output": {"attributes": ["position", "velocity"]}
  })",
                dx, wall, wall, wall + kLength, wall + kHeight);
  return buf;
}

struct Deposit {
  double runout;    ///< distance from the left wall reached by all but 0.5% of the particles (m)
  double speed;     ///< largest particle speed at the end (m/s)
};

Deposit collapse(double dx) {
  const slurry::Scene scene = slurry::parse_scene(column_scene(dx), "column_2d");
  auto sim = slurry::make_simulation(scene);
  sim->advance_to(1.0);
  const auto data = sim->frame({"position", "velocity"});
  const auto& v = data.table("vertex");
  const auto x = v.column_as_double("x"), vx = v.column_as_double("vx"), vy = v.column_as_double("vy");
  std::vector<double> d(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) d[i] = x[i] - 2 * dx;
  const std::size_t k = std::size_t(0.995 * double(d.size()));
  std::nth_element(d.begin(), d.begin() + std::ptrdiff_t(k), d.end());
  // Particles sit half a particle spacing inside the material's edge (8 per cell: dx / sqrt 8 apart).
  Deposit out{d[k] + 0.5 * dx / std::sqrt(8.0), 0};
  for (std::size_t i = 0; i < vx.size(); ++i) out.speed = std::max(out.speed, std::hypot(vx[i], vy[i]));
  return out;
}

TEST(GranularCollapse2D, RunoutMatchesLube2005AndConvergesTowardsIt) {
  const double expected = kLength * (1 + 1.2 * kHeight / kLength);
  double previous_error = 1;
  for (double dx : {1.0 / 128, 1.0 / 256}) {
    const Deposit d = collapse(dx);
    const double error = std::abs(d.runout / expected - 1);
    std::printf("dx 1/%g: runout %.4f m (Lube et al. 2005: %.4f m, %+.1f%%), final speed %.2g m/s\n", 1 / dx,
                d.runout, expected, 100 * (d.runout / expected - 1), d.speed);
    EXPECT_LT(error, 0.12) << "dx " << dx;
    EXPECT_LT(error, previous_error) << "dx " << dx << ": the runout should approach the experiment";
    EXPECT_LT(d.speed, 0.05) << "the deposit should be at rest after 1 s";
    previous_error = error;
  }
}

}  // namespace
